"""Viscous stress and pressure in one solve: a backward-Euler step of the incompressible
Navier-Stokes equations without the advective term, as one saddle-point system,

    u_i - dt L(u)_i + dt G(k)_i = v*_i          (momentum, per unit mass)
                        dt D(u)_i = dt s_i      (continuity)

for the new velocity u and the pressure-like k = p / rho0 of every melt particle. At a creeping
melt's nu dt / dx^2 ~ 1e4 the viscous and pressure forces are both ~1e4 times the inertia;
solving them one after the other (implicit viscosity, then a pressure projection) leaves a
splitting error of the size of the solution in a layer sqrt(nu dt) wide, wider than a bead
(Guermond, Minev & Shen, Comput. Methods Appl. Mech. Engrg. 195, 2006). Solved together, the
step is the discrete Stokes problem itself whatever dt: its velocities do not depend on the
viscosity's size, only on the geometry and the walls (test: squeeze film at 1000 and 12.7 Pa s).

Operators (V: the rest volume, F(r) x = grad W):

* L: Weiler et al.'s (2018) viscosity operator, L(u)_i = sum_j c_ij F ((u_i - u_j) . x_ij) x_ij
  with c_ij = d mu_ij (m_j / rho_j) / rho_i / (r^2 + 0.01 H^2) and d calibrated on the lattice
  (physics/viscosity_weiler2018.py); with the free surface's traction, the strain-energy form
  below, and Weiler's operator only inside the preconditioner, on the solves where it is
  the cheaper stand-in (stokes_inner_operator, "block-triangular preconditioner" below);
* without the traction, a share w (option stokes_viscous_isotropic_share, 0.1 unless given) of
  each pair term is Morris, Fox & Zhu's (1997) Laplacian of the whole velocity difference,
  c'_ij F r^2 (u_i - u_j), rather than its projection on the link (physics/viscosity_morris1997.py).
  In the continuum Weiler's sum is lap u + 2 grad div u and Morris's lap u, so the pair term is
  lap u + 2 (1 - w) grad div u: Espanol & Revenga's (Phys. Rev. E 67, 2003) pair form of the
  Newtonian stress with a bulk viscosity zeta = (5/3 - 2 w) mu (Weiler's sum alone: 5 mu / 3;
  the even blend w = 1/2: div(mu (grad u + grad u^T)), 2 mu / 3; Morris's alone a negative one);
  inside a divergence-free melt every w gives mu lap u. Why not w = 0: Weiler's link is stiff
  along itself only, so a row's diagonal block 1 + dt sum c |F| x x^T is as weak across a plane
  of links as the row's inertia. Without that inertia (the Stokes limit a creeping step is
  close to, nu dt / dx^2 ~ 1e4) the row is singular: Weiler's sum alone does not make the
  discrete Stokes problem well posed at a particle whose few links lie nearly in one plane. The
  pressure's push on such a row grows linearly with its links' tilt out of the plane and the
  viscous hold quadratically, so it is flung, at a speed its inertia, not the flow, sets
  (benchy's window: the particle at the tip's rim, smallest eigenvalue of its block 3.98
  against the melt's median 1.1e5, 1.44 m/s; at the real viscosity, 80x less inertia against
  the same rows, the window lost 18 particles). A share w of Morris's term gives every block
  at least w times its links' sum in every direction (tests/test_stokes.py), so such a row is
  held by viscosity, as its melt neighbours' mean. Morris's term alone lets melt slip under a
  wall: measured side by side (2026-12-05, 2 cores), w = 0 / 0.5 / 1, the bundled bead 0.471 /
  0.491 / 0.560 mm wide at draft, 0.499 / 0.546 / 0.635 mm at standard and 0.4995 / 0.571 /
  0.599 mm at fine (the slicer's 0.45 x 0.2 mm); the squeeze film without the traction at 4
  layers and R / h = 5 0.82 / 0.68 / 0.38 of Stefan's force (under Morris's the melt below the
  film's disc moved at 0.82 of its speed, under Weiler's at 0.94); the bore's profile 1.7 /
  1.3 / 1.1 % of u_max off Poiseuille's at 4 per radius. A small share keeps Weiler's shapes
  and gives the floor: at w = 0 / 0.1 / 0.2 the bundled bead is 0.471 / 0.467 / 0.487 mm wide
  at draft (the same run's scatter: 0.007 mm) and 0.499 / 0.501 / 0.511 mm at standard; at
  w = 0 / 0.1 0.4995 / 0.511 mm at fine at the same height (0.185 / 0.184 mm); the squeeze
  film 0.82 / 0.80 / 0.77 of Stefan's force at 4 layers, and at w = 0 / 0.1 0.958 / 0.938 at 6
  and 1.032 / 1.014 at 8 (2026-12-05, 2 cores). Benchy's 4 x 4 mm window (validation/windows)
  under w = 0.1, at the real viscosity: to its end, nothing lost, no melt faster than 0.086 m/s
  or 4x the nozzle's speed, 7,114 steps in 13.8-14.4 min (under w = 0.05 as well: 7,175 steps,
  nothing lost); under w = 0 on the same day's code it blew up at t = 188.03 s on a particle
  at 1.71 m/s. 0.1 is a choice where the shapes move by 2 % at most (measured above), not a
  derived value;
* G, D: DFSPH's pressure gradient and velocity divergence (physics/dfsph.py), adjoint to each
  other: G(k)_i = sum_j V (k_i + k_j) grad W_ij + sum_b V k_i grad W_ib,
  D(u)_i = sum_j V (u_i - u_j) . grad W_ij + sum_b V (u_i - u_b) . grad W_ib.

Walls (plate, nozzle, bore column, solidified melt) are no-slip at their own velocity v_b. A
wall particle takes the ghost velocity of Adami, Hu & Adams (J. Comput. Phys. 231, 2012,
Eq. 22-23), u_b = 2 v_b - u~_b with u~_b the Shepard average of the melt around it, so that the
velocity vanishes relative to the wall at the wall's surface rather than a kernel's depth
inside it: with u_b = v_b the squeeze film's lubrication pressure came out as for a gap 15 %
(6 layers) to 27 % (4 layers) wider (measured, 2026-12-02). The mirror is exact for a
velocity linear in the distance from the wall and not for a curved one (Macia, Antuono,
Gonzalez & Colagrossi, Prog. Theor. Phys. 125, 2011, analyse its error): at a wall particle
half a spacing deep it shows -u(d) where the profile's continuation is -u(d) + u''(0) d^2, so
the first melt layer's viscous term misses a share of the curvature. Between a plate and a
lid (scene couette, 4 layers across the gap) Poiseuille's parabola came out 1.08x its
amplitude under the pair sum and the squeeze film lost a tenth of its force to it. So without
the traction, with ``stokes_wall_ghost="quadratic"`` (opt-in, below), a melt row next to a wall whose
surface and normal its geometry gives (the plate, a nozzle's flat face, a scene's lid or
disc: ``ParticleState.wall_depth``, ``wall_normal``) fits its own melt in reach, itself
included, with a parabola w(s) = a s + b s^2 through the wall's velocity at the surface
(s: the distance from the surface along the normal, weights W; a 2 x 2 least-squares
system), and each such wall particle at depth d shows that row u_b = v_b + w(-d) =
v_b - a d + b d^2: Morris, Fox & Zhu's (J. Comput. Phys. 136, 1997) per-pair extrapolation
through the wall, one order higher. A wall particle's own support reaches one melt layer,
too few for a parabola; the row's reaches two or three. a and b are linear in the melt's
velocities (the fit's weights are fixed within a step), so the operator stays linear: one
more neighbour pass over the rows next to such walls per product. Rows whose melt in reach
does not all lie on the melt's side of the surface (around a face's edge), or lies at one
distance only, keep Adami's mirror, as do walls without a known surface (the nozzle's flank
and bore, solidified melt). Measured (2026-12-07, 2 cores, validation/couette): Poiseuille's
parabola 0.996 of its amplitude at 4 layers (Adami's 1.076), a sliding lid within 0.4 % of
V; the squeeze film at R / h = 5 and 4 layers 0.90 of Stefan's force (0.80), at 6 layers
1.00. Only one solve at a fixed geometry uses it: a film between a plate and a lid sliding
past each other at 0.24 m/s (4 layers, pair sum) blew up at t = 2 ms under it (melt at
21.5 m/s), so a scene that runs in time refuses it (simulation.py); the cause is not traced.
Before that was found, on strands (validation/strands, "The walls'
quadratic ghost") the ghost moved the nine-section widths by -4 to +5 % of the rounded
rectangle (the bundled bead +7 / +10 / +15 % at draft / standard / fine against +6 / +12 /
+12 %), the 0.1 mm gap at two layers took 26 GMRES iterations a step against 15, and a
two-bead print at two layers across its gap (tests/test_idle.py) carried 38 particles out of
its box on the nozzle against 10, which moved its bead's 99th-percentile height by 0.14 mm
between skipping the nozzle's absence and running it. Under the mirror the same sliding film
ran to its end but showed why a print's melt slides on its nozzle's face: melt sliding along
a particle wall rides its corrugation (validation/couette). The traction's strain-energy form keeps
Adami's mirror (its adjoint sums are built on the Shepard weights). The ghost makes L non-symmetric,
so the system is solved by GMRES (Saad & Schultz, SIAM J. Sci. Stat. Comput. 7, 1986),
restarted and right-preconditioned. For k the preconditioner takes the diagonal of SIMPLE's
approximation of the Schur complement, D B^-1 G with B the momentum rows' 3x3 diagonal blocks
(Patankar & Spalding, Int. J. Heat Mass Transfer 15, 1972; as a preconditioner: Elman, Howle,
Shadid, Shuttleworth & Tuminaro, J. Comput. Phys. 227, 2008); see "Schur approximation" below.
For u, by default (``block_triangular``) an inner conjugate-gradient solve of the viscous rows
given that k, with flexible GMRES outside (see "block-triangular preconditioner" below); or
(``block_diagonal``) the 3x3 diagonal blocks of the momentum rows alone, which leave the
viscous rows' conditioning to GMRES: the bore flow at 8 particles per radius did not converge
in 20,000 iterations with it and converges in 1,160 with the inner solve.
Right preconditioning makes GMRES minimise the true residual; the stop is on what the step
leaves, measured at each restart: the momentum residual relative to the right-hand side, both
through the diagonal blocks (so in velocities), and the largest predicted density error
dt |D(u) - s|. A cycle ends early once GMRES's running residual norm (Saad & Schultz's
|g_{j+1}|, known without forming the iterate) has fallen enough that both criteria, scaled by
that fall, are met; the true residuals then decide. Ran to the full restart length every
cycle, the draft bead took 47 GMRES / 248 inner iterations a step, with the early end 36 /
193: nine-section width 0.465 / 0.467 mm, height 0.198 mm in both (2026-12-03). The
iteration counts quoted below for the bore, film and extension were measured before that.

Continuity source s: what the step removes of the kernel sum's error besides divergence.
``density_source="two-way"`` (the default): (1 - rho_i / rho0) / dt on particles whose kernel
is full; on the rest, where the sum is short of rho0 for lack of neighbours rather than for
expansion, compression only, min(1 - rho_i / rho0, 0) / dt (Bender & Koschier 2017's clamp).
This is Shao & Lo's (Adv. Water Resour. 26, 2003) density-invariant source, its free-surface
particles left to the traction-free condition. Which kernels are full is Marrone et al.'s
(J. Comput. Phys. 229, 2010) test (physics/surface.py): flag 0 (interior) against 1 (surface)
and 2 (the layer under it, whose kernel reaches past the surface), refreshed with the
neighbour lists (each step of a print), and of the interior only the particles his eigenvalue
alone calls interior, lambda > 0.75. Between 0.2 and 0.75 his umbrella scan calls a particle
interior if any neighbour covers its outward normal; such a kernel has lost a quarter of its
second moment: a hole in the melt, not the step's drift. Behind the nozzle's rim, where melt
riding on the tip tears from melt lying on the bead, covered particles sat at kernel sums of
0.70-0.88; the source asked each hole closed within one step, (1 - rho / rho0) dx / dt, and
the next, shorter step asked it again faster: melt at 0.2-0.95 m/s against the nozzle's
0.05-0.07, and the printer's block at x 0.2136 lost 26 particles through the domain's top.
The same block to print time 2.45 s (one after the other, 2 cores, 2026-12-07): flag 0 alone
3,419 steps, 69 / 22 of them with melt 2-4x / over 4x the walls' speed, fastest 0.95 m/s;
with lambda > 0.75 3,260 steps, 17 / 0, 0.122 m/s; compression only 3,162 steps, 0 / 0,
0.119 m/s.
``"summation"``: the clamp everywhere, which never corrects expansion inside the melt, so
what a step's explicit drift leaves expanded stays and grows with the step. Side by side
(validation/strands, "The continuity source both ways", on the relative step with the
eigenvalue bound, 2026-12-07): the strands' interior kernel sums 0.08-0.23 % off on average
against 0.53-1.30 % (0.30-0.62 % against 1.01-2.38 % at twice the step); at twice the step
all six strands narrower, by 2-5 points of the rounded rectangle, at the print's step within
-1 to +3 points of the one-way source, at the same iterations a step. On the lab-frame step
with flag 0 alone (the first table that day) the interior came to 0.01-0.05 % against
0.39-1.13 % and eleven of twelve strands narrower, by up to 11 points; the 0.3 mm collapse's
interior 0.14 % against 1.30 % off, Huppert's coefficient 1.003 against 1.009, in 17 % more
steps (validation/collapse). The constraint is an equality either way, so melt takes tension as freely as
compression. The kernel sum also reads melt stretched at constant volume as compressed (+6 %
at a Hencky strain of 0.36, validation/extension), so either source dilates a stretched
filament; ``"none"`` keeps the steps divergence-free instead.

Free surface: the pressure's symmetric sum gives it zero ambient pressure; Weiler's viscous
sum alone gives it no viscous flux, which is not zero traction. With ``surface_traction`` the
viscous term is instead the derivative of a discrete dissipation, sum_i V mu_i |D_i|^2 with
D_i the strain rate from Bonet & Lok's (1999) corrected gradient, the same gradient D and G
use; its boundary term is then the pressure's, and -p + 2 mu n.D.n, not p alone, vanishes
at the surface (see "free-surface traction" below). The operator is symmetric and I - dt L
is at least the identity: no step amplifies a mode. The corrected gradient does not see a
particle-scale zigzag; Ganzenmueller's (CMAME 286, 2015) hourglass term, Weiler's pair
dissipation of the velocity differences the gradients do not predict, damps it; it vanishes
on linear fields, and inside the melt on quadratic ones (the pair's two gradients average to
the chord's slope), so a Poiseuille profile does not feel it (``stokes_zero_energy_control``,
default 1: Weiler's weight).
Measured (2026-12-03, 2 cores): the extension filament's interior pressure 1.011 of
Trouton's -mu e (1.03-1.09 with the explicit traction correction this replaced); the squeeze
film at R / h = 5 0.73 / 0.85 / 0.92 of Stefan's force at 4 / 6 / 8 layers (0.77 / 0.91 /
0.99 before) in 80-160 GMRES iterations (80-480): its ghost walls slip (below). Without the hourglass term the coarse
film's solution was a zigzag of layers at 0.9 V and ~0 in turn, 0.36 of Stefan's force.
The extension filament (0.125 mm, divergence-free steps) now reaches a strain of 0.5 with
44 GMRES iterations a step and no halving (the explicit correction stalled at 0.45), the mid
radius within 0.6 % of Trouton's to 0.4; there the melt lets go of the stretched end pieces.
Where melt leaves a die (scene die-swell, validation/die_swell) only this form keeps a free
surface the melt does not cross: the jet out of the nozzle's bore swells 1.149 / 1.161 /
1.152 at 4 / 6 / 8 particles per radius (Newtonian creeping swell 1.13, Nickell, Tanner &
Caswell 1974), the streamline from the lip, the particle count and continuity agreeing within
1.5 %; under the pair sum, at 4 per radius, continuity reads 1.247 where the streamline and
the count read 1.116 and 1.074: the jet carries three quarters of the die's flux.
Two things keep it out of prints for now, both measured: Adami's ghost walls slip more under
it (bore flow 6.4 / 4.9 / 2.7 % of u_max at 4 / 6 / 8 per radius against 1.7 / 4.6 % with
Weiler's sum, which did not converge at 8 in 20,000 iterations at a restart of 40 where
this form took 600; at 200 they take 193 and 202, see "Restart";
at 4 the profile sits 0.08 u_max over Poiseuille's throughout; the
ghost's Shepard average stands for the melt's velocity at the wall particle's mirror image,
which it is for the first wall layer only, yet continuing the melt's velocity linearly to the
deeper layers, Morris, Fox & Zhu's (1997) ratio with the surface half a spacing under the
nearest melt, moved the squeeze film's force by 0.3 % and made the bore's staircase worse,
13 %: tried, not kept), and the bundled bead (draft) runs to its end without a halving
but comes out 1.49x the slicer's width with melt 0.12 mm over the gap behind the nozzle and
kernel sums down to 0.56 rho0 at its surface, at 177 GMRES / 1,790 inner iterations a step
(47 / 249 with Weiler's) and 8.4x the wall time. With the inner solve on the form itself
(stokes_inner_operator = 'system', 2026-12-05, alone on 2 cores) it costs 3.4-5.1x: the
draft bead 96 s against 28 s without the traction (23 / 92 against 18 / 46 GMRES / inner a
step), the standard bead 305 s against 60 s. The shape keeps it out: 0.678 mm wide at draft and
0.667 mm at standard (1.51x and 1.48x the slicer's 0.450 mm), the interior melt's kernel
sums 1.9 and 2.6 % under rho0 on average (0.8 % without the traction): its particles
drift apart, though that is not what makes it wide (last item below). The continuity rows
hold the corrected divergence at zero, and that is not the rate of change of the kernel sum
(the uncorrected divergence is): with no density source the
draft bead's interior kernel sums drifted 10 % on average, the densest 76 % over rho0, and
the compression-only source removes one side of that drift only. Tried that day, draft
bead (width, interior kernel sums' mean error) and die swell at 4 per radius (the
streamline's swell, Nickell's 1.13), none kept:
* D and G uncorrected (the form unchanged): 0.535 mm, 0.8 %; swell 1.226: the discrete
  traction-free condition needs the pressure's boundary term to be the form's;
* D uncorrected, G corrected: 0.548 mm, 1.0 %; swell 1.155 (continuity's reading 1.21);
* D less its inconsistency, D_plain - sym(A_i) : (I - M_i) with A_i the corrected velocity
  gradient: equal to the corrected D on linear fields, so the swell stays 1.130, and it
  sees the particle-scale modes the corrected D cannot; 0.661 mm, 1.8 %: not those modes;
* particle shifting after each step, -A dx |u| dt grad C with A = 2 (Skillen, Lind, Stansby
  & Rogers, CMAME 265, 2013), tangential only where Marrone's test (physics/surface.py) flags
  the surface or its next layer: 0.584 mm, 4.2 %;
* the kernel sum's source both ways on the particles Marrone's test calls interior (flag 0),
  compression only elsewhere: the interior held (0.09 % at draft, 0.06 % at standard) and
  the strand still 0.665 / 0.642 mm wide (draft / standard, 1.48x / 1.43x). So the drift
  inside the melt does not make the width: the surface's layers (a third of the standard
  bead's melt under 0.9 rho0 with this source, 41 % without) or the traction's flow itself
  does, and which one is open.

Free-surface rows (``stokes_surface_rows``, the pair sum only): by default a row on the free
surface (Marrone's flag 1) keeps the continuity row, which leaves its pressure to whatever
continuity asks; on the bundled bead at standard spacing, 1 mm around the nozzle, such rows
stood at a median -207 kPa where the traction-free condition their own velocities ask is -68
(validation/strands, trace_face.py). With ``"traction"`` the row is instead
s_ii (k_i - 2 nu_i n.D_i.n) = 0, the free-surface rows of incompressible SPH (Shao & Lo 2003
set p = 0 there) with the viscous normal stress the issue's traction-free surface carries:
n Marrone's normal, D_i the symmetric part of Bonet & Lok's corrected gradient of the
velocities (walls at their ghosts), so 2 nu n.D.n = sum_j ((u_j - u_i) . n) (q_i . V grad W_ij)
with q_i = 2 nu M_i^-T n, linear in u; s_ii, the row's Schur diagonal, scales it so that a
pressure error weighs in it as in a continuity row (the preconditioner and the stop read it
unchanged). The row is not symmetric with anything; GMRES does not need it to be. Measured
(2026-12-07, 2 cores, against the continuity rows): the die's jet at 4 per radius carries
the die's flux (swell read by continuity 1.177, the streamline 1.170, the lattice 1.144,
against 1.248 / 1.117 / 1.074: tests/test_die_swell.py; at 6 per radius its surface
iteration still cycles, 1.255-1.286); the extension filament (0.125 mm,
no source) at 1.000 / 1.003 / 1.014 of R0 exp(-e t / 2) at strains 0.1 / 0.2 / 0.3 (0.997 /
0.998 / 1.007), its middle's pressure 1.82x Trouton's -mu e against 2.24x; but the bundled bead 0.535 /
0.553 mm wide at draft / standard (+19 / +23 % over the rounded rectangle of its own area,
against +6 / +12 %) at 45 / 52 GMRES iterations a step
(19 / 20), the melt under the face carrying the same 0.74 of a full gap's flow; and the
surface's particles, which no continuity row holds any more, compress: at the end kernel
sums up to 1.15 / 1.22 rho0, the material area +1 / +7 % (validation/strands, "The free
surface's rows under the pair sum"). So the surface's pull is not what widens the strands,
and a surface row needs its volume kept too before it can be a print's default; the option
stays off.

Compressibility: the continuity rows are the melt's rate form of p = K (rho / rho0 - 1),
dt D(u) - (k - k_n) / c^2 = dt s with c^2 = K / rho0 (material.bulk_modulus_pa; Tait's law
gives K ~ 1-2 GPa for polymer melts). With incompressible rows a fragment of melt that the
flow has left with one or two neighbours at the edge of their kernels has a near-null pressure
mode: its rows' coefficients are grad W near the support's edge, and the pressure that holds
it off a wall grows without bound as they vanish. Benchy's 4 x 4 mm window stalled on such a
pair (two particles 0.38 spacings apart, 1.9 from the substrate, k = +-90 m^2/s^2 and
growing): 20,000 GMRES iterations at a relative residual of 1.3e-5, after four halvings, the
residual all in those two rows (2026-12-03). K bounds the mode by the melt's own stiffness
and adds dx / (c^2 dt) to the Schur complement's diagonal (6 % of its value inside the squeeze
film at dt = 1e-4 s: a preconditioner's weight). The volume a step lets the melt lose is its
pressure change over K, 1e-4 for a 0.15 MPa rise, and the bulk's solution is unchanged: the
draft bead's width 0.467-0.471 mm and height 0.194-0.198 mm at K = 0.5, 1.5 and 6 GPa and
incompressible, its run-to-run scatter, in the same 26-27 GMRES iterations a step (the bead
0.474 / 0.196 mm with the source below). The continuity source removes only the compression
beyond the elastic k_n / c^2 that k_n already holds, min(1 + k_n / c^2 - rho / rho0, 0) / dt:
counted in both, the pressure of a compression no flow could relieve grew by c^2 times it
every step, and the paper's block (unscaled, draft) blew up at t = 0.76 s in a drip at the
nozzle's edge, pressures of +-1-4 MPa alternating between neighbours; with the source
corrected it ran past 1.0 s (with incompressible rows to 1.40 s, as far as either was run).
A quasi-static solve (a steady state) leaves the compressibility out.

Tolerance: the solve stops when the velocity error its residual stands for is 3e-4 of the
step's velocities and the largest density error is 3e-4 (``stokes_momentum_tolerance``,
``stokes_density_tolerance``; why 3e-4, not 1e-3: "Norm" below; the figures in this section
were measured at 1e-3 in the Euclidean norm). The velocity error counts the pressure's: the continuity
residual w_k leaves k wrong by about -sigma w_k (the preconditioner's Schur inverse), which
moves the melt by dt G of it, so the measure is |B^-1 (w_u - dt G(-sigma w_k))|. With the bulk
modulus in the rows, a density residual r leaves k free by up to c^2 r (1.2e3 m^2/s^2, 1.5 MPa,
at 1e-3 for PLA): inside the melt the viscous coupling turns that into little motion, but a
fragment of a few particles feels it with its inertia only. Measured on benchy's 4 x 4 mm
window (2026-12-04): with the momentum rows' residual alone, a fragment of 4-6 particles the
departing nozzle tore off moved at 0.08-0.56 m/s, its velocity alternating from step to step,
and flung one particle out of the window; counting the pressure's part, no melt moved faster
than 0.08 m/s over the same second, in 936 steps instead of 1,139 (the flung particle had
shortened the CFL step) at 15 / 91 GMRES / inner iterations a step against 7 / 43. Each step
solves for its velocities afresh, so their error is not inherited; it moves a particle by
1e-3 of its step's travel. Compression a step leaves
shows in the next kernel sum and the source removes it; expansion stays (the source counts
none, above), at most 1e-3 of a particle's volume a step, and measured it does not add up.
Measured 2026-12-04 on 2 cores (draft bead, three runs at dt x 0.95, 1, 1.05 each): at 1e-3
against 1e-5 9.2 / 47 GMRES / inner iterations a step against 26 / 139, 11 against 24 s,
nine-section width 0.464 against 0.471 mm, height 0.197 mm in both, material area 0.0810
against 0.0806 mm^2 (the three runs of each spread 0.007 mm, 0.002 mm and 0.004 mm^2),
interior kernel sums 0.82 and 0.81 % off on average. Benchy's window, first second: 8.3
against 32 GMRES a step, 12 against 54 s; the collapse at 10 Pa s: Huppert's coefficient
0.967 against 0.971, 39 against 173 s. Tried and not kept: carrying each row's leftover
expansion into the next step's source. A fragment of a few particles cannot be compressed
by any flow, so its elastic term took the carried volume, k ~ c^2 times it, and that pressure
flung the fragment (its particles at 0.1-0.3 m/s, the sign alternating step by step: benchy's
window stopped at t = 187.84 s at 1e-5 as at 1e-3; resumed without the carry, it ran on).

Norm: GMRES minimises the residual in its inner product, and a restarted GMRES advances only
as far as that norm sees. The stop reads the residual as T w, with
    T = [B^-1, dt B^-1 G sigma; 0, c]:
the momentum rows through B^-1 (B ~ 1 + nu dt / dx^2 ~ 1e4 for a melt) together with the
velocity the continuity rows' pressure error moves, and the continuity rows by the density
criterion, c = (dt / dx) (tol_u / tol_rho) |B^-1 rhs|, so that a density error at its
tolerance weighs as a velocity error at its own. In the Euclidean norm the two kinds of row
are weighed ~1e4-1e8 apart from how the stop weighs them: GMRES spends its iterations on
momentum residual the stop discounts and leaves continuity residual the stop counts in full.
Measured (2026-12-04): the print of tests/test_idle at an inner tolerance of 0.3 stopped at
t = 0.551 s, where the nozzle had left 168 melt rows nearly at rest (|B^-1 rhs| 5e-5 m/s), the
criterion at 1.4-2.7 times the right-hand side, 97 % of it the pressure error of continuity
residuals of 1e-5 in eight rows, for 20,000 iterations after four halvings, with or without
LGMRES's augmentation (Baker, Jessup & Manteuffel, SIAM J. Matrix Anal. Appl. 26, 2005; tried,
not kept). So GMRES runs in the inner product <x, y> = (T x) . (T y) (weighted GMRES, Essai,
Numer. Algorithms 18, 1998, there with a diagonal weight): each basis vector keeps its image
T v_l, Gram-Schmidt reads the images and updates w and T w alike (T is linear), and each
iteration costs one more pressure-gradient sum, for T of the new vector. The running residual
|g_{j+1}| is then |T r|, the criterion itself, and the Krylov operator is unchanged (a left
preconditioner T would have multiplied A P^-1, near the identity, by T's 1e-4-to-1e4 spread).
A diagonal weight first tried (momentum rows |B^-1|_F^2 / 3, continuity rows the squared
column norm of sigma dt B^-1 G) leaves out B^-1's anisotropy and the cross terms: on benchy's
window it stalled at t = 188.75 s, where it read 3.4x the criterion (not kept).
Measured side by side (2 cores, GMRES / inner iterations a step, T's norm against the
Euclidean, tolerances 1e-3 unless said): test_idle's print at inner 0.1 8.9 / 61 against
14.1 / 73, at 0.3 9.6 / 35 against a stall; the standard bundled bead at 0.1 13.8 / 81
against 20.8 / 128 (width 0.494 against 0.496 mm), at 0.3 15.2 / 42; the collapse's first
second (R = H = 4 mm, 10 Pa s, 0.5 mm, surface traction) at 0.1 37.5 / 347 against 48.9 / 495
and at 0.3 39.2 / 152 against unfinished after 300 s. GMRES now stops where the criterion
allows and no further, which shows what the criterion is worth: a residual reads a smooth
error (L / dx)^2 too small (B^-1 for A^-1, sigma for the Schur complement's inverse; the
preconditioner's own estimate P^-1 r read the film's error 100x too small as well). On the
film at 1 Pa s with a noisy pressure memory the velocities' error against the converged
solution was 7.5 % of the fastest at 1e-3, 2.5 % at 3e-4, 0.9 % at 1e-4 (127 / 153 / 180
iterations), where the Euclidean norm had over-solved to 0.7 % in 240 (tests/test_stokes.py).
At 1e-3 and inner 0.3 the standard bead came out 2 % wider than the Euclidean's (0.511 against
0.500 mm, three runs each at dt x 0.95, 1, 1.05, each spreading 0.007-0.010 mm) and benchy's
window stopped at t = 189.94 s on a particle flung past the speed limit; at 3e-4 the bead is
0.499 mm (20.3 / 56 a step) and the window runs to its end. Hence the defaults: this norm,
tolerances of 3e-4, inner 0.3 (validation/windows has the window's side-by-side figures).

Free fragments: melt that touches no wall (no wall or bore particle within H of any of its
particles, through melt neighbours) moves as a body in free flight: every pair term of L and
G is equal and opposite and along the pair, so its momentum rows sum to m du/dt = m g and
their moments to a constant angular momentum. Its rigid motion is the momentum block's
eigenvalue 1, against ~1 + nu dt / dx^2 ~ 1e4 for its deformation: the tolerance, which
reads velocities through the diagonal blocks, does not see it, and GMRES, minimising the
whole residual, leaves it where its Krylov space puts it. On benchy's window fragments of
four particles the departing nozzle tore off sped up step after step, smoothly, to 0.27 m/s
and left the domain (60 particles in one run to t = 184.15 s). So each solve labels the free
fragments (anchoring spreads from the walls through melt neighbours; the rest take the
smallest index of their fragment) and, before every residual it measures, sets each
fragment's translation and rotation to the ones that leave its rows no net force and no
net moment: a coarse correction on the rigid modes, as deflation removes known near-null
modes from a Krylov solve (Nicolaides, SIAM J. Numer. Anal. 24, 1987). Their deformation is
stiff, and the tolerance sees it.
With Morris's term in L (any isotropic share) a pair's viscous force is not along the
pair: a rigid rotation is no longer near-null (it dissipates) and the rows' moments do not
cancel, so only the translation is set; GMRES meets the rotation like any stiff mode.

Initial guess: the solve starts from the melt's present velocity v_n, or (option
stokes_initial_guess = 'extrapolated') from each melt particle's velocity extrapolated from
its last two steps, v_n + (dt / dt_n-1)(v_n - v_n-1), the simplest of the predictors that
start a solve from earlier solutions (Fischer, Comput. Methods Appl. Mech. Engrg. 163, 1998).
Particles entering the domain start their history at their own velocity; a solve that is no
step (quasi-static) and an idle span, which sets the melt at rest, void it. The stop is the
same either way. The extrapolated start is closer (benchy's window, 0.12 s from t = 183.92 s:
starting residual 0.056 against 0.084, density error 0.0011 against 0.0029, medians; 16.8 /
84 against 18.5 / 101 GMRES / inner iterations a step; test_idle's print 11.4 / 37 against
13.1 / 57), but it carries forward whatever error the stop leaves in modes it reads weakly,
where v_n alone keeps it: over benchy's whole window the extrapolated start had more melt
flung faster than 4x the nozzle, not fewer iterations (validation/windows, 2026-12-04). Not
the default, then. Those figures were the one-way density source's; with the two-way source
(see "Continuity source") test_idle's print takes 9.6 / 23.4 extrapolated against 9.3 / 23.1
from v_n (one way: 9.8 / 24.2 against 10.4 / 29.9; 2026-12-07): the step's expansion, which
one way left for the next step to meet, no longer makes v_n a poor start. With the walls'
speed counted as their fastest particle's (steps 20 % longer, same day) it turned again: two
ways 10.2 / 26.1 against 10.1 / 29.2, one way 9.0 / 26.0 against 8.4 / 23.4. A saving that
changes sign with the step is no reason to change the default.

Restart: GMRES keeps stokes_restart Krylov vectors (200 by default, stored by melt row) and
starts again from its iterate when they run out; a restart throws the space away, and a solve
that needs several cycles loses the superlinear convergence the whole space would give it
(restarted GMRES can stagnate where the full one converges: Saad, Iterative Methods for
Sparse Linear Systems, 2nd ed., SIAM 2003, ch. 6).
Solves that took hundreds of iterations at the earlier 40 were restart-bound, not
preconditioner-bound (measured 2026-12-05, 2 cores): the bore flow at 8 per radius under
Weiler's sum had not converged in 20,000 iterations (1,321 s) and converges in 193 (35 s) at
200, with the traction 202 against 600 (36 against 118 s), the same profile; the collapse at
R = H = 3 mm, 0.2 mm, 1 Pa s to 1.5 s 102 / 465 GMRES / inner a step at 120 against 189 / 770
at 40, 269 against 400 s, the same front to four digits. Tried there before this was seen,
and not kept: SIMPLE's Schur approximation solved by an inner conjugate-gradient solve in
place of its diagonal (halved the late steps' iterations at 40, the same as the diagonal's at
120: 140 / 117 against 135 / 121, at ~3 extra pressure passes an iteration), a tighter inner
viscous tolerance (0.1: 312 s at 40), and a two-level inner solve with the translations of
aggregates of 6^3 spacings as its coarse space (264 / 157 against 344 / 268 at 40). Prints
need no long restart (the draft bead: 18 a step, the same at 40 and 120) and pay nothing for
it: their melt is a few thousand of their 36,000-107,000 particles.

Inner precision: the inner solve on Weiler's sum preconditions; it stops at a residual fall
of 0.3 and flexible GMRES outside keeps whatever it returns, so its neighbour pass reads the
direction p and c F in f32 (cF_in, with the wall's ghost factor folded in and every wall's p
held at zero, so the pass has no branch on the phase) and sums in f64; its scalars (r . z,
p . q) and its vectors by row stay f64. f32 resolves a residual fall of ~1e-6, far below the
inner tolerances in use (the option refuses one under 1e-4). On the strain-energy form the
direction stays f64 (its passes read z). Cached kernel gradient: V F(|x_ij|) is stored per
list slot in the setup (VF) and the Schur diagonal, pressure and divergence passes read it
instead of evaluating the kernel; it is the same
expression in the same precision, so those passes give the same bits. Measured on the paper
block (unscaled, draft) resumed at t = 1.664 s, 96 steps, alone on 2 cores (2026-12-06): 448-464
ms a step before, 361-387 with the f32 inner pass, 288 with the cache too, at the same 17.9 /
105.0 GMRES / inner iterations a step (the cache alone changes no digit); the inner pass 1.0-1.3
ms -> 0.35-0.67, the pressure pass 2.0 -> 0.79 ms (Taichi's kernel profiler). The bundled
bead at standard, one after the other: 160 s before, 124 s after, the same 823 steps at 20.5 /
55.0 and 20.4 / 55.0 GMRES / inner iterations a step, W / H 0.501 / 0.181 and 0.504 / 0.181 mm
(the inner solve's rounding moves the trajectory, not the shape).

Inner right-hand side: the inner solve for basis vector v_j starts from v_j's velocity error
e_j = v_u - dt G(-sigma v_k), the vector whose B^-1 the criterion's image T v_j already holds
(see "Norm"). So with the criterion's norm it is read back as B (T v_j)_u, B kept by row from
the setup (Bm), and the operator's product adds dt G(k) = v_u - e_j for the preconditioned
vector's k instead of summing it over the pairs again: of the three pressure sums a GMRES
iteration took, the criterion's is the one left. T v_j comes from Gram-Schmidt's updates, as
v_j does, and B (B^-1 e) returns e to eps cond(B), ~1e-11 at nu dt / dx^2 ~ 1e5, far below the
solve's 3e-4; the true residual at each restart decides the stop as before. A GMRES iteration
also takes five launches instead of eight (v_j stored by the launch that multiplies by it, T w
in the operator's launch, Gram-Schmidt's passes in one): Taichi's Python side costs ~0.15 ms
a launch here. Measured side by side on one host (2 cores, 2026-12-06, code `7dea78f` then
this): the paper block resumed at t = 1.664 s, 65 steps, 262 -> 221 and later 301 -> 255 ms a
step (1.18x; the host's pace drifted between the pairs), the same 20.58 / 121.66 GMRES / inner
iterations a step; the bundled bead at standard 117.5 -> 106.2 s (1.11x; the processes 125.7 ->
110.5 s), the same 823 steps, W / H 0.504 / 0.181 -> 0.503 / 0.181 mm; the paper block to print
time 0.9 s 217.3 -> 191.3 s (1.14x), the same 1,760 steps. On the squeeze film every path
(the criterion's or the Euclidean norm, block-triangular or block-diagonal preconditioner)
takes the iterations it took before, and each lies as far from the default's velocities as
before (1.0e-5 to 2.5e-5 of the fastest, at tolerances of 1e-6).

Orthogonalisation: each GMRES iteration makes its new vector orthogonal to the basis, in the
criterion's inner product, by classical Gram-Schmidt (the dots with every earlier vector in
one sweep, their combination removed in the next: two sweeps whatever the basis' size, where
the modified process takes one per vector). One pass loses orthogonality in proportion to
eps times the square of the condition number of the vectors it is given, a second pass
restores it to working precision ("twice is enough": Giraud, Langou & Rozloznik, Comput. Math.
Appl. 50, 2005). In GMRES that condition number grows about as the residual falls (Paige,
Rozloznik & Strakos, SIAM J. Matrix Anal. Appl. 28, 2006, for the modified process), so a solve
stopped at a fall of 3e-4 stays far from where one pass would lose its basis; and
orthogonality lost would cost iterations, not accuracy: the stop reads the true residual at
each restart. One pass (``stokes_gram_schmidt_passes``, 1 by default; PETSc's GMRES takes one
unless told otherwise as well) took the same iterations as two on every case measured: the
squeeze film 24 / 61 GMRES / inner iterations at the default tolerances and 61 / 142 at 1e-6,
velocities 2e-8 and 8e-8 of the fastest apart; the bore flow at 8 per radius 202 / 942 and the
block-diagonal preconditioner's 464 (three restarts) at 4, the same profile. Daniel, Gragg,
Kaufman & Stewart's test (Math. Comp. 30, 1976: a second pass where the first removed more of
the vector than it left) asked for it in 23 of the film's 24 iterations and 60 of 61, so it is
not offered. Measured side by side (2026-12-06, 2 cores, two passes then one): the paper
block resumed at t = 1.664 s, 65 steps at 20.58 / 121.66 in every run, 273 -> 237, 264 -> 228
and 247 -> 221 ms a step (1.12-1.16x) in three pairs,
270 -> 262 and 258 -> 237 ms (1.03-1.09x) in two more, Gram-Schmidt 1.55 -> 0.78 ms an
iteration (15 -> 8 % of the kernel time); benchy's window to print time 179 s 93.9 -> 88.8 s
(1.06x), the same 1,609 steps, 14.1 / 55 -> 13.9 / 52 a step (rounding); the bundled bead at
standard 107.6 -> 104.5 s (1.03x), the same 823 steps, W / H 0.503 / 0.181 -> 0.501 / 0.182
mm; the collapse at 0.4 mm to 3 s 100.3-105.4 -> 96.6-98.0 s (1.02-1.09x), the same 83 steps,
Huppert's coefficient 0.9804 and 0.9805 of his.

An unconverged solve is reported as such (``converged``); the caller must not keep its step.
"""

import logging
import math
from dataclasses import dataclass

import numpy as np

from taichi_mex.backend import current, ti
from taichi_mex.core.state import FLUID, INLET, SOLID
from taichi_mex.physics.viscosity_morris1997 import lattice_laplacian_factor as morris_lattice_factor

log = logging.getLogger(__name__)

#: passes over the melt's neighbour lists (walls' passes counted as whole ones): a GMRES
#: iteration of the block-triangular preconditioner (the criterion's pressure sum and the
#: operator's product: the walls' ghosts, the strain-energy form's three passes and one of
#: its own; the inner solve's G(k) is read from T v, see "Inner right-hand side"), and an
#: inner iteration on the strain-energy form (ghosts, three, its walls' adjoint sums); one
#: on Weiler's sum is one pass
OUTER_PASSES = 6
ENERGY_INNER_PASSES = 4
#: one Gram-Schmidt pass over one earlier Krylov vector (its dots and its update), in passes
#: over the neighbour lists: fitted to the collapse at 0.2 mm with two Gram-Schmidt passes an
#: iteration (steps of 48 and 121 GMRES iterations a solve, 2.2 and 8.2 s, 2 cores,
#: 2026-12-05; 2.0 ms a pass, 0.69 ms a vector for both), where Weiler's inner operator's long
#: solves spend more on these sweeps than on their passes
KRYLOV_SWEEP_PASSES = 1.0 / 6.0

#: the share of Morris's isotropic term in each viscous pair term where the pair sum is the
#: system's viscous term and none is given, the rest Weiler's projected one (see "Operators")
ISOTROPIC_SHARE = 0.1

#: on a CPU, the melt rows from which the solve's loops leave the calling thread (see
#: serial()): its loops over the rows' own vectors, and its loops over their neighbours with
#: more than one thread (options serial_rows, serial_pair_rows)
SERIAL_ROWS = 65536
SERIAL_PAIR_ROWS = 4096


@dataclass
class StokesResult:
    converged: bool
    iterations: int
    #: |B^-1 momentum residual| / |B^-1 momentum right-hand side| (B: diagonal blocks)
    momentum_residual: float
    #: largest density error the step leaves, dt |D(u) - s| less the compression the melt's
    #: bulk modulus allows, (k - k_n) / c^2 (-)
    density_error_max: float
    #: mean of it over the melt (-)
    density_error_mean: float
    #: the block-triangular preconditioner's inner conjugate-gradient iterations, all together
    inner_iterations: int = 0
    #: wall time of a quasi-static solve (s), its first compilation included (0: not timed)
    wall_s: float = 0.0
    #: melt rows in fragments that touch no wall, whose rigid motion the solve set exactly
    free_rows: int = 0

    def figures(self) -> dict:
        """The solve's figures as a scene's summary reports them."""
        return {"stokes_iterations": self.iterations, "stokes_converged": self.converged,
                "stokes_inner_iterations": self.inner_iterations, "solve_wall_s": self.wall_s,
                "stokes_momentum_residual": self.momentum_residual,
                "stokes_density_error_max": self.density_error_max}


@ti.data_oriented
class CoupledStokes:
    #: Krylov basis and scratch, rebuilt by every solve: not part of a checkpoint
    checkpoint_skip = ("basis", "w", "z", "X", "rhs", "ghost", "shepard", "wall_row", "cF", "cF_in", "VF",
                       "Binv", "sigma", "part", "Minv", "Ag", "T", "hg", "q", "eacc", "Binv_in",
                       "surf_rhs", "anchored", "comp", "cl_n", "cl_c", "cl_Jinv", "cl_a", "cl_b", "changed",
                       "Zb", "cg_x", "cg_r", "cg_p", "cg_q", "cg_z", "cg_part", "kpart", "total", "alpha",
                       "cg_rz", "cg_rz0", "cg_beta", "cg_it", "cg_done",
                       "dots_out", "c2inv", "coef", "tw", "tb", "crho", "reuse", "Bm", "cg_g", "begin_serial",
                       "gs_passes",
                       # the machine's, not the run's: a resume elsewhere takes its own
                       "on_cpu", "serial_rows", "pair_rows")

    def __init__(self, state, grid, kernel, viscosity, viscous, rho0: float, volume_m3: float,
                 spacing_m: float, rows, opts, bulk_modulus_pa: float | None = None,
                 rows_capacity: int | None = None):
        """viscosity: the melt's MeltViscosity; viscous: the ImplicitViscosity whose pair
        coefficients L uses; rows: a FluidIndex over the melt; opts: the run's DFSPHOptions
        (its stokes_* fields); bulk_modulus_pa: the melt's K (None or the option off:
        incompressible); rows_capacity: the most melt rows a solve can have (None: every
        particle), the length of the Krylov vectors, which are stored by row."""
        self.state = state
        self.grid = grid
        self.K = kernel
        self.visc = viscosity
        self.viscous = viscous
        self.rho0 = float(rho0)
        self.V = float(volume_m3)
        # continuity rows are multiplied by dx: their residual is then a velocity, as the
        # momentum rows' is, and GMRES's one norm weighs both alike
        self.dx = float(spacing_m)
        self.rows = rows
        self.m = int(opts.stokes_restart)
        self.exact = opts.stokes_norm == "criterion"
        self.extrapolated = opts.stokes_initial_guess == "extrapolated"
        self.tol_u = float(opts.stokes_momentum_tolerance)
        self.tol_rho = float(opts.stokes_density_tolerance)
        self.max_iterations = int(opts.stokes_max_iterations)
        self.traction = bool(opts.stokes_surface_traction)
        # the pair sum's free surface (see "Free-surface rows"): Marrone's surface rows take
        # -p + 2 mu n.D.n = 0 in place of continuity
        self.surface_rows = opts.stokes_surface_rows == "traction" and not self.traction
        #: a body force on the melt above a plane: (ax, ay, az) in m/s^2 and the plane's
        #: height in state coordinates (m); a scene that drives its melt through a die by a
        #: pressure drop sets it (ScenePlan.drive); none by default
        self.drive = (0.0, 0.0, 0.0, math.inf)
        # the viscous pair term (see "Operators"): the share of Morris's Laplacian of the whole
        # velocity difference in it, the rest Weiler's link-projected one
        share = opts.stokes_viscous_isotropic_share
        if share is not None and self.traction:
            raise ValueError("the pair sum's viscous term is not used with the surface traction "
                             "(RunOptions.validate refuses the combination)")
        self.w_iso = 0.0 if self.traction else (ISOTROPIC_SHARE if share is None else float(share))
        self.isotropic = self.w_iso > 0.0
        self.morris_ratio = 0.0
        if self.isotropic:
            self.morris_ratio = (1.0 / morris_lattice_factor(kernel, spacing_m, volume_m3)) / viscous.d
        self.hourglass = float(opts.stokes_zero_energy_control)
        self.summation_source = opts.stokes_density_source in ("summation", "two-way")
        # the source both ways where the kernel is full (see "Continuity source"): Marrone's
        # free-surface flags, from the detector the simulation attaches (attach_surface)
        self.two_way = opts.stokes_density_source == "two-way"
        self.surface = None
        # 1 / c^2 = rho0 / K (s^2/m^2): see "Compressibility"; a field, so that a
        # quasi-static solve can leave it out without a second compilation
        self.inv_c2 = (self.rho0 / float(bulk_modulus_pa)
                       if bulk_modulus_pa and opts.stokes_compressible else 0.0)
        self.c2inv = ti.field(ti.f64, shape=())
        self.c2inv[None] = self.inv_c2
        self.flexible = opts.stokes_preconditioner == "block_triangular"
        self.inner_tol = float(opts.stokes_inner_tolerance)
        self.gs_passes = int(opts.stokes_gram_schmidt_passes)  # see "Orthogonalisation"
        # the inner solve's operator (see "block-triangular preconditioner"): the system's own
        # viscous block (with the traction, the strain-energy form) or Weiler's pair sum
        # ('auto': per step, see "block-triangular preconditioner"); the next solve's choice
        mode = opts.stokes_inner_operator if self.traction else "weiler2018"
        self.inner_auto = mode == "auto"
        self.inner_energy = mode == "system"
        # per inner operator (energy form or not): the work of its latest solve, in passes
        # over the melt (None: not yet tried), and the solves that used it
        self.inner_work = {False: None, True: None}
        self.inner_solves = {False: 0, True: 0}
        # per inner operator: its first solve's work since it was last chosen ('auto')
        self.inner_ref = {False: None, True: None}
        self.inner_max = int(opts.stokes_inner_max_iterations)
        cap = state.capacity
        # free-surface traction, the strain-energy form (see "Free surface"): per particle the
        # corrected gradient's inverse moment matrix, the stress 2 nu D of the vector being
        # multiplied (stored times that inverse, see _energy), a wall's adjoint sum, the
        # resulting acceleration and its constant part from the walls' velocities
        shape = cap if self.traction else 1
        self.Minv = ti.Matrix.field(3, 3, ti.f64, shape=shape)
        # the free-surface rows: whether row i is one, its outward normal n, 2 nu M^-T n (so
        # that 2 nu n.D.n = sum_j ((u_j - u_i) . n) (q . V grad W_ij)) and the walls' constant
        # share of that sum
        scap = cap if self.surface_rows else 1
        self.srow = ti.field(ti.i32, shape=scap)
        self.sn = ti.Vector.field(3, ti.f64, shape=scap)
        self.sq = ti.Vector.field(3, ti.f64, shape=scap)
        self.s_rhs = ti.field(ti.f64, shape=scap)
        self.Ag = ti.Matrix.field(3, 3, ti.f64, shape=shape)
        self.T = ti.Matrix.field(3, 3, ti.f64, shape=shape)
        self.hg = ti.Vector.field(3, ti.f64, shape=shape)
        self.q = ti.Vector.field(3, ti.f64, shape=shape)
        self.eacc = ti.Vector.field(3, ti.f64, shape=shape)
        self.surf_rhs = ti.Vector.field(3, ti.f64, shape=shape)
        self.affine = ti.field(ti.i32, shape=())  # 1: walls' velocities in the strain too
        # Vectors that only their own row reads (w, the Krylov basis and its images T v, the
        # inner solve's x, r, z and q, Weiler's blocks) are stored by row (slot), the rest by
        # particle (neighbours read z, the inner solve's p, the state). A print's melt is a
        # few thousand rows among ~100,000 particles sorted by cell: by particle index every
        # vector operation gathered scattered cache lines (benchy's window, one solve: 166
        # against 143 ms, Gram-Schmidt 0.60 against 0.37 ms a pass; 2026-12-04)
        vec4 = lambda: ti.Vector.field(4, ti.f64, shape=cap)  # noqa: E731
        self.X, self.rhs, self.w, self.z = vec4(), vec4(), vec4(), vec4()
        # the restart's m + 1 vectors (three sets with the criterion's norm and the flexible
        # preconditioner) by melt row: on benchy's window 107,121 particles hold a few thousand
        # melt rows, and sized by particle they took most of the run's memory
        self.rows_cap = min(int(rows_capacity), cap) if rows_capacity else cap
        rcap = self.rows_cap
        self.basis = ti.Vector.field(4, ti.f64, shape=(self.m + 1, rcap))
        self.ghost = ti.Vector.field(3, ti.f64, shape=cap)  # Shepard melt velocity at a wall
        self.werr = ti.Vector.field(3, ti.f64, shape=cap)  # momentum residual less dt G(dk)
        self.shepard = ti.field(ti.f64, shape=cap)  # sum_j W_bj over the melt
        # the quadratic wall ghost (see "Walls"), by melt row: whether its fit holds, the
        # wall's normal and the row's distance from its surface, the fit's inverse normal
        # matrix (m00, m01, m11), its weights' sums (A, C) and, per application, the fitted
        # slope and curvature of z's velocity along the normal
        self.quadratic = bool(opts.stokes_wall_ghost == "quadratic") and not self.traction
        fcap = cap if self.quadratic else 1
        self.fit_ok = ti.field(ti.i32, shape=fcap)
        self.fit_n = ti.Vector.field(3, ti.f64, shape=fcap)
        self.fit_s = ti.field(ti.f64, shape=fcap)
        self.fit_m = ti.Vector.field(3, ti.f64, shape=fcap)
        self.fit_AC = ti.Vector.field(2, ti.f64, shape=fcap)
        self.fit_a = ti.Vector.field(3, ti.f64, shape=fcap)
        self.fit_b = ti.Vector.field(3, ti.f64, shape=fcap)
        self.wall_row = ti.field(ti.i32, shape=cap)  # walls within reach of the melt
        self.n_walls = ti.field(ti.i32, shape=())
        self.cF = ti.field(ti.f64, shape=(cap, grid.max_neighbours))
        # V F(|x_ij|) by list slot, in the state's precision: the pressure and divergence
        # passes read it instead of evaluating the kernel (the same value to the bit)
        self.VF = ti.field(float, shape=(cap, grid.max_neighbours))
        self.Binv = ti.Matrix.field(3, 3, ti.f64, shape=cap)
        self.sigma = ti.field(ti.f64, shape=cap)
        # the inner solve's preconditioner on Weiler's sum, by row (not particle): its
        # diagonal blocks, read once a row per inner iteration, stream in order (on the
        # strain-energy form the inner solve reads Binv)
        self.Binv_in = ti.Matrix.field(3, 3, ti.f64, shape=cap)
        # the criterion's norm: T w and every basis vector's image T v_l, and the density
        # criterion's weight c in T (see "Norm")
        self.tw = ti.Vector.field(4, ti.f64, shape=cap if self.exact else 1)
        self.tb = ti.Vector.field(4, ti.f64, shape=(self.m + 1, rcap) if self.exact else (1, 1))
        self.crho = ti.field(ti.f64, shape=())
        self.dt = ti.field(ti.f64, shape=())
        self.block = 256
        self.n_blocks = max(1, (cap + self.block - 1) // self.block)
        self.part = ti.field(ti.f64, shape=(self.m + 1, self.n_blocks))
        self.coef = ti.field(ti.f64, shape=self.m + 1)
        self.out3 = ti.Vector.field(3, ti.f64, shape=())
        self.total = ti.field(ti.f64, shape=())
        self.alpha = ti.field(ti.f64, shape=())  # the inner iteration's step length
        # the inner solve's scalars stay on the device between its launches: r . z now and at
        # the start, the direction's beta, the iteration count and whether it has stopped
        self.cg_rz = ti.field(ti.f64, shape=())
        self.cg_rz0 = ti.field(ti.f64, shape=())
        self.cg_beta = ti.field(ti.f64, shape=())
        self.cg_it = ti.field(ti.i32, shape=())
        self.cg_done = ti.field(ti.i32, shape=())
        self.chunk = int(opts.cg_chunk)
        live = current()
        self.on_cpu = live.get("arch", "cpu") == "cpu"
        threads = max(1, live.get("threads", 1))
        self.serial_rows = int(opts.serial_rows if opts.serial_rows is not None
                               else SERIAL_ROWS)
        self.pair_rows = int(opts.serial_pair_rows if opts.serial_pair_rows is not None
                             else (SERIAL_PAIR_ROWS if threads > 1 else 10**9))
        self.dots_out = np.zeros(self.m + 1)  # _dots' results for the host (H's column)
        # v_n-1 for the extrapolated initial guess (see "Initial guess"): a state field, so
        # that it moves with the particles' sort and is checkpointed; none without it (every
        # kernel reads it only under ti.static(self.extrapolated))
        self.previous_dt = 0.0  # s; 0: no history (first step, after an idle span)
        self.v_prev = None
        if self.extrapolated:
            self.v_prev = state.add("previous_velocity", 3)
            state.on_append.append(self._appended)
        self.force_flag = ti.field(ti.i32, shape=cap)  # walls wall_force sums over
        # block-triangular preconditioner: each basis vector's preconditioned image (flexible
        # GMRES keeps them, the preconditioner being an inner iterative solve) and the inner
        # conjugate-gradient solve's vectors
        inner = cap if self.flexible else 1
        self.Zb = ti.Vector.field(4, ti.f64, shape=(self.m if self.flexible else 1,
                                                    rcap if self.flexible else 1))
        vec3 = lambda: ti.Vector.field(3, ti.f64, shape=inner)  # noqa: E731
        self.cg_x, self.cg_r, self.cg_q, self.cg_z = vec3(), vec3(), vec3(), vec3()
        # what the inner solve's neighbour pass reads per pair, in f32 (see "Inner precision"):
        # the direction p by particle (walls' held at zero) and c F with the wall's ghost
        # factor folded in
        self.cg_p = ti.Vector.field(3, ti.f32, shape=inner)
        self.cF_in = ti.field(ti.f32, shape=(inner, grid.max_neighbours if self.flexible else 1))
        self.kpart = ti.field(ti.f64, shape=inner)  # the preconditioned vector's k
        # the inner solve's right-hand side from the criterion's image T v_j (see "Inner
        # right-hand side"): the momentum rows' diagonal blocks B by row, and dt G(k) of the
        # preconditioned vector's k, which the operator's product adds instead of a pass
        self.reuse = self.flexible and self.exact
        self.Bm = ti.Matrix.field(3, 3, ti.f64, shape=self.rows_cap if self.reuse else 1)
        self.cg_g = ti.Vector.field(3, ti.f64, shape=self.rows_cap if self.reuse else 1)
        self.begin_serial = 0 if self.reuse else 1
        self.cg_part = ti.field(ti.f64, shape=(2, self.n_blocks))
        # free fragments (see "Free fragments"): whether a melt row's fragment touches a wall,
        # its fragment's label (the smallest row index in it), and per label the fragment's
        # size, centroid, inverse inertia and the rigid correction's sums
        self.anchored = ti.field(ti.i32, shape=cap)
        self.comp = ti.field(ti.i32, shape=cap)
        self.cl_n = ti.field(ti.f64, shape=cap)
        self.cl_c = ti.Vector.field(3, ti.f64, shape=cap)
        self.cl_Jinv = ti.Matrix.field(3, 3, ti.f64, shape=cap)
        self.cl_a = ti.Vector.field(3, ti.f64, shape=cap)
        self.cl_b = ti.Vector.field(3, ti.f64, shape=cap)
        self.changed = ti.field(ti.i32, shape=())

    # ------------------------------------------------------------------ operator pieces
    @ti.func
    def _pair(self, cF, du, xij):
        """The viscous pair term for the velocity difference du: Weiler's cF (du . x) x, with
        Morris's (the lattice's ratio) cF r^2 du blended in at the weight w_iso."""
        out = cF * du.dot(xij) * xij
        if ti.static(self.isotropic):
            out = (1.0 - self.w_iso) * out + (self.w_iso * self.morris_ratio) * cF * xij.norm_sqr() * du
        return out

    @ti.func
    def _setup_task(self, i, slot, j, xij, acc: ti.template()):
        """Cache c F; accumulate the 3x3 diagonal block (acc[0:9]) and the walls' constant
        terms of the right-hand side: momentum (acc[9:12]) and continuity (acc[12])."""
        r2 = xij.norm_sqr()
        cF = 0.0
        VF = ti.cast(0.0, self.VF.dtype)
        if r2 < self.K.H * self.K.H and r2 > 0.0:
            F = self.K.F(xij.norm())
            VF = self.V * F
            cF = self.viscous._coef(i, j, r2) * F
            if self.state.phase[j] != FLUID:
                vb = ti.cast(self.state.v[j], ti.f64)
                gb = 2.0 * vb if self.shepard[j] > 0.0 else vb  # Adami's ghost, less u~_b
                if ti.static(self.quadratic):
                    if self._fitted(i, j):
                        d = ti.cast(self.state.wall_depth[j], ti.f64)
                        ac = self.fit_AC[i]
                        gb = (1.0 + d * ac[0] - d * d * ac[1]) * vb
                w = self._pair(cF, gb, xij)
                for d in ti.static(range(3)):
                    acc[9 + d] += w[d]
                acc[12] += vb.dot(self._corrected(i, VF * xij))
                if ti.static(self.surface_rows):
                    if self.srow[i] == 1:
                        acc[13] += gb.dot(self.sn[i]) * self.sq[i].dot(ti.cast(VF * xij, ti.f64))
        self.cF[i, slot] = cF
        self.VF[i, slot] = VF
        if ti.static(self.flexible):
            f = 1.0
            if self.state.phase[j] != FLUID and self.shepard[j] > 0.0:
                f = 2.0  # Adami's ghost: p_b = -p_i, so the pair sees 2 p_i
            self.cF_in[i, slot] = ti.cast(f * cF, ti.f32)
        for a in ti.static(range(3)):
            if ti.static(self.isotropic):
                acc[4 * a] += (self.w_iso * self.morris_ratio) * cF * r2
                for b in ti.static(range(3)):
                    acc[3 * a + b] += (1.0 - self.w_iso) * cF * xij[a] * xij[b]
            else:
                for b in ti.static(range(3)):
                    acc[3 * a + b] += cF * xij[a] * xij[b]

    @ti.func
    def _energy_block_task(self, k, slot, j, xkj, acc: ti.template()):
        """The strain-energy form's 3x3 diagonal block, -dL_k/du_k = sum_i nu_i (|a|^2 I +
        a a^T) over a = a_ik, the weight of u_k in A_i: acc[0:3] sum_j c_kj (a_kk is its
        negative), acc[3:12] the melt neighbours' terms (a_jk = c_jk). The ghosts' share
        through u~_b is left out: this block preconditions, it is not the operator."""
        r2 = xkj.norm_sqr()
        if r2 < self.K.H * self.K.H and r2 > 0.0:
            c = self._c(k, xkj)
            for d in ti.static(range(3)):
                acc[d] += c[d]
            if self.state.phase[j] == FLUID:
                a = self._c(j, -xkj)
                nu = ti.cast(self.visc.eta_of(j), ti.f64) / self.rho0
                blk = nu * (a.norm_sqr() * ti.Matrix.identity(ti.f64, 3) + a.outer_product(a))
                for p in ti.static(range(3)):
                    for r in ti.static(range(3)):
                        acc[3 + 3 * p + r] += blk[p, r]

    @ti.func
    def _schur_task(self, i, slot, j, xij, acc: ti.template()):
        """acc[0:3]: G(e_i)_i = sum over all neighbours of V grad W corrected at i; acc[3]: sum
        over melt neighbours of G(e_i)_j . B_j^-1 G(e_i)_j (G(e_i)_j = -that pair's term);
        V F from the setup's cache (_setup_task fills it in the loop before)."""
        r2 = xij.norm_sqr()
        if r2 < self.K.H * self.K.H and r2 > 0.0:
            c = ti.cast(self._corrected(i, self.VF[i, slot] * xij), ti.f64)
            for d in ti.static(range(3)):
                acc[d] += c[d]
            if self.state.phase[j] == FLUID:
                acc[3] += c.dot(self.Binv[j] @ c)

    # ------------------------------------------------------------ free-surface traction
    # Weiler's pair sum is the dissipation of pair-wise relative velocities: where a support is
    # cut by a free surface, its boundary term is that of no viscous flux, not of zero
    # traction. The strain-energy form takes the viscous term as the derivative of a discrete
    # dissipation, the way Bonet & Lok (CMAME 180, 1999) derive forces from an energy with
    # their corrected gradient:
    #     Phi = sum_i V mu_i |D_i|^2,   D_i = sym(A_i),   A_i = sum_j (u_j - u_i) (x) c_ij,
    #     c_ij = M_i^-1 V grad W_ij,    L(u)_k = -(1 / (rho0 V)) dPhi / du_k
    #           = T_k sum_j c_kj - sum_i T_i c_ik + (walls' ghosts, below),  T = 2 nu D.
    # Inside a full support the first sum vanishes and the second is div(2 nu D); at a free
    # surface the first is the same boundary term as the pressure's k_i sum_j c_ij (G = -D^T
    # from the same c), so the discrete natural condition is -p n + 2 mu D n = 0. Phi >= 0 and
    # the operator is its Hessian: I - dt L is symmetric positive definite in the mass norm,
    # so no mode can grow (the explicit boundary correction this replaces had a negative
    # eigenvalue on a bead's side and blew up at t = 0.355 s, 2026-12-02). Walls enter A_i with
    # Adami's ghost u_b = 2 v_b - u~_b; u~_b is linear in the melt's velocities, so the ghost's
    # derivative is part of L: wall b gathers q_b = sum_i T_i c_ib and passes it back with the
    # Shepard weights, L(u)_k += sum_b W_bk q_b / sum_j W_bj. The force on a wall is
    # -dPhi/dv_b (translating every velocity leaves Phi unchanged: momentum is conserved).
    # The corrected gradient is blind to a particle-scale zigzag (u_j - u_i vanishes in
    # symmetric pairs): such modes cost no dissipation; they are not amplified (I - dt L >= I)
    # but nothing damps them either (measured below).
    @ti.func
    def _corrected(self, i, gV):
        """V grad W with Bonet & Lok's correction (with the traction treatment only)."""
        if ti.static(self.traction):
            return self.Minv[i] @ ti.cast(gV, ti.f64)
        else:
            return gV

    @ti.func
    def _square(self, acc: ti.template(), o: ti.template()):
        """The 3x3 matrix stored row by row in acc[o:o + 9]."""
        return ti.Matrix([[acc[o], acc[o + 1], acc[o + 2]], [acc[o + 3], acc[o + 4], acc[o + 5]],
                          [acc[o + 6], acc[o + 7], acc[o + 8]]])

    @ti.func
    def _moment_task(self, i, slot, j, xij, acc: ti.template()):
        """acc: -sum V F x x^T, whose inverse corrects the kernel gradient."""
        r2 = xij.norm_sqr()
        if r2 < self.K.H * self.K.H and r2 > 0.0:
            x = ti.cast(xij, ti.f64)
            acc -= self.V * ti.cast(self.K.F(ti.sqrt(r2)), ti.f64) * x.outer_product(x)

    @ti.func
    def _moment_inverse(self, i):
        """M_i^-1, Bonet & Lok's correction of row i's kernel gradient."""
        M = ti.Matrix.zero(ti.f64, 3, 3)
        self.grid.for_each_listed(i, self._moment_task, M)
        Minv = ti.Matrix.identity(ti.f64, 3)
        # a neighbourhood in a plane or on a line has no inverse: left uncorrected
        if ti.abs(M.determinant()) > 1e-6:
            Minv = M.inverse()
        return Minv

    @ti.func
    def _surface_setup(self, n, S: ti.template()):
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            self.Minv[i] = self._moment_inverse(i)

    @ti.func
    def _gV(self, xij):
        """V grad W(x_i - x_j) in f64, uncorrected (every pass evaluates F alike: the form's
        symmetry holds to the bit)."""
        x = ti.cast(xij, ti.f64)
        return self.V * ti.cast(self.K.F(x.norm()), ti.f64) * x

    @ti.func
    def _c(self, i, xij):
        """c_ij = M_i^-1 V grad W(x_i - x_j)."""
        return self.Minv[i] @ self._gV(xij)

    @ti.func
    def _wall_velocity(self, b):
        """Wall b's velocity in the strain: Adami's ghost 2 v_b - u~_b (v_b where no melt is
        near, or the bore's column); the part in v_b only when ``affine`` is set."""
        u = ti.Vector.zero(ti.f64, 3)
        s = self.shepard[b]
        if s > 0.0:
            u = -self.ghost[b] / s
        if self.affine[None] == 1:
            vb = ti.cast(self.state.v[b], ti.f64)
            u += 2.0 * vb if s > 0.0 else vb
        return u

    @ti.func
    def _velocity(self, j):
        """z's velocity at melt particle j, or wall j's in the strain."""
        u = ti.Vector.zero(ti.f64, 3)
        if self.state.phase[j] == FLUID:
            zj = self.z[j]
            u = ti.Vector([zj[0], zj[1], zj[2]])
        else:
            u = self._wall_velocity(j)
        return u

    @ti.func
    def _strain_task(self, i, slot, j, xij, acc: ti.template()):
        r2 = xij.norm_sqr()
        if r2 < self.K.H * self.K.H and r2 > 0.0:
            zi = self.z[i]
            ui = ti.Vector([zi[0], zi[1], zi[2]])
            acc += (self._velocity(j) - ui).outer_product(self._c(i, xij))

    @ti.func
    def _hg_coef(self, i, j, r2):
        """The hourglass term's pair weight: Weiler's c F at rest density, symmetric in (i, j)."""
        mu = ti.cast(self.visc.eta_of(i), ti.f64)
        if self.state.phase[j] == FLUID:
            mj = ti.cast(self.visc.eta_of(j), ti.f64)
            mu = 2.0 * mu * mj / (mu + mj + 1e-30)
        F = ti.cast(self.K.F(ti.sqrt(r2)), ti.f64)
        return self.hourglass * self.viscous.d * mu * self.V / self.rho0 / (
            r2 + self.viscous.eps) * F

    @ti.func
    def _hourglass_task(self, i, slot, j, xij, acc: ti.template()):
        """acc[0:9] P_i = sum_j w x x^T (melt pairs halved), acc[9:12] sum_j w x, with
        w = kappa_ij (e_ij . x_ij) and e_ij the pair's velocity difference less what the
        gradients predict: (u_i - u_j) - (A_i + A_j) x_ij / 2, or - A_i x_ib at a wall."""
        r2 = xij.norm_sqr()
        if r2 < self.K.H * self.K.H and r2 > 0.0:
            x = ti.cast(xij, ti.f64)
            zi = self.z[i]
            fluid = self.state.phase[j] == FLUID
            Aj = self.Ag[j] if fluid else self.Ag[i]  # a wall's: i's own
            half = 0.5 if fluid else 1.0
            e = ti.Vector([zi[0], zi[1], zi[2]]) - self._velocity(j) - 0.5 * (self.Ag[i] + Aj) @ x
            w = self._hg_coef(i, j, x.norm_sqr()) * e.dot(x)  # as _adjoint_task: f64
            for a in ti.static(range(3)):
                acc[9 + a] += w * x[a]
                for b in ti.static(range(3)):
                    acc[3 * a + b] += half * w * x[a] * x[b]

    @ti.func
    def _adjoint_task(self, b, j, xbj, acc: ti.template()):
        """q_b = sum over melt i of T_i c_ib + w_ib x_ib (x_ib = -x_bj)."""
        if self.state.phase[j] == FLUID:
            x = -ti.cast(xbj, ti.f64)
            zi = self.z[j]
            e = ti.Vector([zi[0], zi[1], zi[2]]) - self._wall_velocity(b) - self.Ag[j] @ x
            acc += self.T[j] @ self._gV(-xbj) + self._hg_coef(j, b, x.norm_sqr()) * e.dot(x) * x

    @ti.func
    def _divergence_task(self, k, slot, j, xkj, acc: ti.template()):
        """acc[0:3]: sum_j V grad W_kj; acc[3:6]: -sum_i T_i c_ik + the walls' ghost terms
        (T here is T M^-1: c_ik = -M_i^-1 V grad W_ki)."""
        r2 = xkj.norm_sqr()
        if r2 < self.K.H * self.K.H and r2 > 0.0:
            c = self._gV(xkj)
            f = ti.Vector.zero(ti.f64, 3)
            if self.state.phase[j] == FLUID:
                f = self.T[j] @ c
            elif self.shepard[j] > 0.0:
                w = ti.cast(self.K.W(ti.sqrt(r2)), ti.f64)
                f = w / self.shepard[j] * self.q[j]
            for d in ti.static(range(3)):
                acc[d] += c[d]
                acc[3 + d] += f[d]

    @ti.func
    def _energy(self, n, S: ti.template()):
        """eacc = L(z's velocity) in the strain-energy form (ghost sums set), with the
        hourglass term: its gradient part rides on T (T_i + P_i), its pair part on hg."""
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            A = ti.Matrix.zero(ti.f64, 3, 3)
            self.grid.for_each_listed(i, self._strain_task, A)
            self.Ag[i] = A
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            A = self.Ag[i]
            nu = ti.cast(self.visc.eta_of(i), ti.f64) / self.rho0
            T = nu * (A + A.transpose())
            acc = ti.Vector.zero(ti.f64, 12)
            self.grid.for_each_listed(i, self._hourglass_task, acc)
            # stored times M_i^-1: every later read multiplies a kernel gradient by T_i M_i^-1
            # (c_ij = M_i^-1 V grad W_ij), one 3 x 3 read a pair instead of two
            self.T[i] = (T + self._square(acc, 0)) @ self.Minv[i]
            self.hg[i] = ti.Vector([acc[9], acc[10], acc[11]])
        ti.loop_config(serialize=S > 1)
        for wslot in range(self.n_walls[None]):
            b = self.wall_row[wslot]
            acc = ti.Vector.zero(ti.f64, 3)
            self.grid.for_each_neighbour(b, self._adjoint_task, acc)
            self.q[b] = acc
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            k = self.rows.index[slot]
            acc = ti.Vector.zero(ti.f64, 6)
            self.grid.for_each_listed(k, self._divergence_task, acc)
            self.eacc[k] = self.T[k] @ ti.Vector([acc[0], acc[1], acc[2]]) + \
                ti.Vector([acc[3], acc[4], acc[5]]) + self.hg[k]

    # ------------------------------------------------------------ the quadratic wall ghost
    @ti.func
    def _fitted(self, i, b):
        """Whether the pair (melt row i, wall b) takes the quadratic ghost."""
        return self.fit_ok[i] == 1 and self.state.wall_depth[b] > 0.0

    @ti.func
    def _nearest_wall_task(self, i, slot, j, xij, acc: ti.template()):
        """acc: (r^2, j) of the nearest wall particle whose surface is known."""
        if self.state.phase[j] != FLUID and self.state.wall_depth[j] > 0.0:
            r2 = ti.cast(xij.norm_sqr(), ti.f64)
            if r2 < self.K.H * self.K.H and r2 < acc[0]:
                acc[0] = r2
                acc[1] = ti.cast(j, ti.f64)

    @ti.func
    def _fit_weight(self, i, j, xij):
        """(W_ij, s_j): melt j's kernel weight and its distance from row i's wall surface."""
        w = ti.cast(self.K.W(xij.norm()), ti.f64)
        sj = self.fit_s[i] - self.fit_n[i].dot(ti.cast(xij, ti.f64))
        return w, sj

    @ti.func
    def _fit_moment_task(self, i, slot, j, xij, acc: ti.template()):
        if self.state.phase[j] == FLUID and j != i:
            w, sj = self._fit_weight(i, j, xij)
            if w > 0.0:
                if sj > 0.0:
                    acc[0] += w * sj * sj
                    acc[1] += w * sj * sj * sj
                    acc[2] += w * sj * sj * sj * sj
                else:
                    acc[3] += 1.0

    @ti.func
    def _fit_coef(self, i, w, s):
        """A melt particle's weights in row i's fitted slope and curvature (a, b): weight w,
        distance s from the wall's surface."""
        m = self.fit_m[i]
        return ti.Vector([w * (m[0] * s + m[1] * s * s), w * (m[1] * s + m[2] * s * s)])

    @ti.func
    def _fit_sum_task(self, i, slot, j, xij, acc: ti.template()):
        if self.state.phase[j] == FLUID and j != i:
            w, sj = self._fit_weight(i, j, xij)
            acc += self._fit_coef(i, w, sj)

    @ti.func
    def _fit_setup(self, n, S: ti.template()):
        """Per melt row next to a wall of known surface: a parabola w(s) = a s + b s^2 through
        the wall's velocity at its surface (s = 0), fitted to the melt in reach (the row
        itself included) by least squares weighted with W; a wall particle at depth d then
        shows the pair w(-d) = -a d + b d^2 (see "Walls"). Rows whose melt in reach does not
        all lie on the melt's side of that surface, or lies at one distance only, keep
        Adami's ghost."""
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            self.fit_ok[i] = 0
            near = ti.Vector([1e300, -1.0], ti.f64)
            self.grid.for_each_listed(i, self._nearest_wall_task, near)
            if near[1] >= 0.0:
                b = ti.cast(near[1], ti.i32)
                nrm = ti.cast(self.state.wall_normal[b], ti.f64)
                si = nrm.dot(ti.cast(self.state.x[i] - self.state.x[b], ti.f64)) \
                    - ti.cast(self.state.wall_depth[b], ti.f64)
                self.fit_n[i] = nrm
                self.fit_s[i] = si
                if si > 0.0:
                    w0 = ti.cast(self.K.W(0.0), ti.f64)
                    m = ti.Vector([w0 * si * si, w0 * si * si * si, w0 * si * si * si * si, 0.0])
                    self.grid.for_each_listed(i, self._fit_moment_task, m)
                    det = m[0] * m[2] - m[1] * m[1]
                    if m[3] == 0.0 and det > 1e-6 * m[0] * m[2]:
                        self.fit_m[i] = ti.Vector([m[2] / det, -m[1] / det, m[0] / det])
                        ac = self._fit_coef(i, w0, si)
                        self.grid.for_each_listed(i, self._fit_sum_task, ac)
                        self.fit_AC[i] = ac
                        self.fit_ok[i] = 1

    @ti.func
    def _fit_slope_task(self, i, slot, j, xij, acc: ti.template()):
        if self.state.phase[j] == FLUID and j != i:
            w, sj = self._fit_weight(i, j, xij)
            c = self._fit_coef(i, w, sj)
            u = self.z[j]
            for d in ti.static(range(3)):
                acc[d] += c[0] * u[d]
                acc[3 + d] += c[1] * u[d]

    @ti.func
    def _fit_slopes(self, n, S: ti.template()):
        """fit_a, fit_b: the fitted slope and curvature of z's velocities (melt only, the
        walls' velocity part is in the right-hand side) at every fitted row; like the walls'
        ghosts, computed with each product, so after a solve they hold the solution's (its
        last product is the residual's, at z = X)."""
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            if self.fit_ok[i] == 1:
                c = self._fit_coef(i, ti.cast(self.K.W(0.0), ti.f64), self.fit_s[i])
                ui = self.z[i]
                acc = ti.Vector([c[0] * ui[0], c[0] * ui[1], c[0] * ui[2],
                                 c[1] * ui[0], c[1] * ui[1], c[1] * ui[2]])
                self.grid.for_each_listed(i, self._fit_slope_task, acc)
                self.fit_a[i] = ti.Vector([acc[0], acc[1], acc[2]])
                self.fit_b[i] = ti.Vector([acc[3], acc[4], acc[5]])

    @ti.func
    def _shepard_task(self, b, j, xij, acc: ti.template()):
        if self.state.phase[j] == FLUID:
            acc += self.K.W(xij.norm())

    @ti.func
    def _ghost_task(self, b, j, xij, acc: ti.template()):
        if self.state.phase[j] == FLUID:
            w = self.K.W(xij.norm())
            u = self.z[j]
            acc += w * ti.Vector([u[0], u[1], u[2]])

    @ti.func
    def _pressure_pair(self, i, j, gV, gi):
        """Pair (i, j)'s part of G(k)_i for z's k: k_i gi + k_j (V grad W corrected at j), the
        second term only from melt (a wall has no k); gi: V grad W corrected at i."""
        g = self.z[i][3] * gi
        if self.state.phase[j] == FLUID:
            g += self.z[j][3] * self._corrected(j, gV)
        return g

    @ti.func
    def _apply_task(self, i, slot, j, xij, acc: ti.template()):
        self._apply_pair(i, slot, j, xij, acc, True)

    @ti.func
    def _apply_velocity_task(self, i, slot, j, xij, acc: ti.template()):
        self._apply_pair(i, slot, j, xij, acc, False)

    @ti.func
    def _apply_pair(self, i, slot, j, xij, acc: ti.template(), pressure: ti.template()):
        """acc[0:3]: L's linear part (Weiler's; the strain-energy form adds its own), acc[3:6]:
        G(k) (pressure; else left at zero), acc[6]: D(u) (linear parts)."""
        cF = self.cF[i, slot]
        zi = self.z[i]
        ui = ti.Vector([zi[0], zi[1], zi[2]])
        gV = self.VF[i, slot] * xij
        if self.state.phase[j] == FLUID:
            zj = self.z[j]
            uj = ti.Vector([zj[0], zj[1], zj[2]])
            l = self._pair(cF, ui - uj, xij)
            gi = self._corrected(i, gV)
            for d in ti.static(range(3)):
                if ti.static(not self.traction):
                    acc[d] += l[d]
            if ti.static(pressure):
                g = self._pressure_pair(i, j, gV, gi)
                for d in ti.static(range(3)):
                    acc[3 + d] += g[d]
            acc[6] += (ui - uj).dot(gi)
            if ti.static(self.surface_rows):
                if self.srow[i] == 1:
                    acc[7] += (uj - ui).dot(self.sn[i]) * self.sq[i].dot(ti.cast(gV, ti.f64))
        else:
            ug = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            if self.shepard[j] > 0.0:
                ug = self.ghost[j] / self.shepard[j]
            if ti.static(self.quadratic):
                if self._fitted(i, j):
                    d = ti.cast(self.state.wall_depth[j], ti.f64)
                    ug = d * self.fit_a[i] - d * d * self.fit_b[i]
            l = self._pair(cF, ui + ug, xij)  # u_i - u_b, u_b = 2 v_b - u~_b: linear part
            gi = self._corrected(i, gV)
            for d in ti.static(range(3)):
                if ti.static(not self.traction):
                    acc[d] += l[d]
            if ti.static(pressure):
                g = self._pressure_pair(i, j, gV, gi)
                for d in ti.static(range(3)):
                    acc[3 + d] += g[d]
            acc[6] += ui.dot(gi)
            if ti.static(self.surface_rows):
                if self.srow[i] == 1:
                    acc[7] += (-ug - ui).dot(self.sn[i]) * self.sq[i].dot(ti.cast(gV, ti.f64))

    @ti.func
    def _viscous_of_z(self, n, S: ti.template()):
        """The walls' Shepard sums of z's melt velocities (their ghosts) and, with the surface
        traction, eacc = the strain-energy form's L of z's velocity."""
        ti.loop_config(serialize=S > 1)
        for wslot in range(self.n_walls[None]):
            b = self.wall_row[wslot]
            acc = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            self.grid.for_each_neighbour(b, self._ghost_task, acc)
            self.ghost[b] = acc
        if ti.static(self.quadratic):
            self._fit_slopes(n, S)
        if ti.static(self.traction):
            self._energy(n, S)

    @ti.func
    def _apply(self, n, out: ti.template(), S: ti.template(), pressure: ti.template()):
        """out = A z on the melt rows (z: the preconditioned vector); pressure False: dt G(z's
        k) read from cg_g instead of summed over the pairs (see "Inner right-hand side")."""
        self._viscous_of_z(n, S)
        dt = self.dt[None]
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            acc = ti.Vector.zero(ti.f64, 8)
            if ti.static(pressure):
                self.grid.for_each_listed(i, self._apply_task, acc)
            else:
                self.grid.for_each_listed(i, self._apply_velocity_task, acc)
            zi = self.z[i]
            if ti.static(self.traction):
                e = self.eacc[i]
                for d in ti.static(range(3)):
                    acc[d] += e[d]
            gk = ti.Vector([dt * acc[3], dt * acc[4], dt * acc[5]])
            if ti.static(not pressure):
                gk = self.cg_g[slot]
            krow = self.dx * (acc[6] - self.c2inv[None] / dt * zi[3])
            if ti.static(self.surface_rows):
                if self.srow[i] == 1:
                    krow = (zi[3] - acc[7]) / self.sigma[i]
            out[slot] = ti.Vector([zi[0] - dt * acc[0] + gk[0], zi[1] - dt * acc[1] + gk[1],
                                   zi[2] - dt * acc[2] + gk[2], krow])

    @ti.func
    def _precondition(self, n, v: ti.template(), S: ti.template()):
        """z = M^-1 v on the melt rows."""
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            vi = v[slot]
            u = self.Binv[i] @ ti.Vector([vi[0], vi[1], vi[2]])
            self.z[i] = ti.Vector([u[0], u[1], u[2], self.sigma[i] * vi[3]])

    # ------------------------------------------------- block-triangular preconditioner
    # P = [A, dt G; 0, -S~] with S~^-1 = sigma (below) approximating the inverse of the Schur
    # complement S = D A^-1 dt G (positive: D is G's adjoint), and A^-1 applied by an inner
    # conjugate-gradient solve:
    #     k = -sigma v_k,   u = A~^-1 (v_u - dt G(k)).
    # The system's own lower block is 0 - S, hence the sign: with +sigma the eigenvalues split
    # into clusters at +1 and -1 and the bore flow took 1.4-2x the outer iterations (measured).
    # With exact A^-1 and S^-1 every eigenvalue of the preconditioned system is 1 (Elman,
    # Silvester & Wathen, Finite Elements and Fast Iterative Solvers, 2nd ed. 2014, ch. 9),
    # so the outer iterations stop depending on nu dt / dx^2 and on the particle count; the
    # block diagonal leaves the viscous rows' conditioning, ~(size / dx)^2, to GMRES. A~ is the
    # symmetric part of the momentum block: Weiler's sum with each wall neighbour counted
    # twice (Adami's ghost, u_b = 2 v_b - u~_b, with u~_b ~ u_i), without the free-surface
    # correction; an inner solve varies with its right-hand side, hence flexible GMRES
    # (Saad, SIAM J. Sci. Comput. 14, 1993), which keeps each preconditioned basis vector.
    # With the surface traction the momentum block is the strain-energy form, not Weiler's
    # sum, and A~ differs from it most where the corrected gradient does, in the surface's
    # layers (Bonet & Lok's correction up to 10x there). Option stokes_inner_operator =
    # 'system' makes the inner solve invert the form itself: it is the Hessian of a
    # dissipation, ghosts and hourglass term included, so symmetric and at least the identity
    # (tests/test_stokes.py checks both and that it is the system's block), and the inner
    # CG takes its 3 x 3 diagonal blocks as preconditioner. Measured on the collapse at 0.2 mm
    # (R = H = 4 mm, 1 Pa s, 25,280 melt rows; 2026-12-05, 2 cores, beside other runs), GMRES
    # iterations a step, inner tolerance 0.3 / run to 3e-3:
    #     thin current (t = 0.605 s, dt 7.4 ms):  Weiler's 572-671 / 330-344, the form 61-65 / 53-57
    #     tall cylinder (t = 0, two steps):         Weiler's ~76 / 68-73,     the form ~99
    # The form's iteration is four passes over the melt against Weiler's one: 13-16 ms against
    # about 3. Alone on 2 cores (a step each after compilation, 2026-12-05): the thin current
    # (dt 14.6 ms) 45 / 351 GMRES / inner iterations and 6.4 s against 566 / 1,274 and 39.6 s
    # with Weiler's, the tall cylinder 96 / 1,239 and 19.1 s against 71 / 488 and 3.4 s. The
    # 0.5 mm collapse (10 Pa s, 30 s): 49 / 289 GMRES / inner a step against 47 / 139; the
    # squeeze film 29 / 120 against 24 / 61. So neither operator serves a whole run. With
    # 'auto' each solve picks: each operator is tried once (the first two solves), then a
    # solve takes the one whose latest solve cost fewer passes over the melt's neighbour lists
    # (OUTER_PASSES a GMRES iteration, 4 or 1 an inner iteration, KRYLOV_SWEEP_PASSES for
    # each earlier Krylov vector Gram-Schmidt goes over: counts, so a run makes the same
    # choices every time, whatever the machine's speed).
    # A count goes stale as the flow changes: the operator in use is also left once its
    # solves cost twice what they did when it was chosen (its first solve then), so each
    # doubling of the cost tries the other again. Without that rule the 0.2 mm collapse
    # kept Weiler's: the form, tried on the tall cylinder's second step (5,500 passes), was
    # never retried while Weiler's grew towards it, 23 s a step at t = 0.58 s. With it
    # (2026-12-05, 2 cores, alone): the form on 75 of the 170 steps (the 2nd and 33rd, then
    # from the 98th on, when Weiler's solves had grown from 600-1,000 to 8,700 passes), the
    # same front, 1,109 s against 2,264 s on the form throughout (validation/peer). Tried and
    # not kept: conjugate gradients on the form preconditioned by a Weiler solve (flexible,
    # two or three iterations): 98-110 a step on the tall cylinder, 1,556 on the thin current
    # (Weiler's sum is no spectrally close stand-in for the form there).
    # Measured (2026-12-02, 2 cores): bore flow at 4 per radius 6.2 s against 31.5 s with the
    # block diagonal; 8 per radius converges (it did not in 20,000 iterations). Tried and not
    # kept: BiCGStab on the whole momentum block (traction and ghosts included) as the inner
    # solve: 4.2 s on the bore, but 6 s a solve against 0.5-1.4 s on a bead's first melt, whose
    # outer iterations the free-surface traction sets (without the traction: ~85 outer
    # iterations whatever the melt's size; with it 160 at 192 melt particles, 2,600 at 416;
    # both with the earlier Schur approximation below).
    #
    # Schur approximation. sigma_i = 1 / (D B^-1 G)_ii, the diagonal of SIMPLE's D B^-1 G
    # (B: the momentum rows' 3x3 diagonal blocks), assembled exactly from the pairs. Its
    # inertial limit (B = I) is DFSPH's diagonal factor; in the creeping limit it is a local
    # form of Cahouet & Chabard's (Int. J. Numer. Methods Fluids 8, 1988) nu M^-1, which this
    # solver took before, nu_i / dt + alpha_i / dt^2. That one assumes the viscous and the
    # pressure operators scale alike everywhere; here they do not: a free-surface particle has
    # half its neighbours, a wall row counts its ghosts twice, and Bonet & Lok's correction
    # makes D and G up to 10x larger at the surface (|M^-1| up to 10-19 on a draft bead). On
    # matrices taken from a bead (256 melt particles, eigenvalues of sigma S spread over
    # 0.0014-3.2 with Cahouet & Chabard's), FGMRES with an exact inner solve needed 112 outer
    # iterations against 316 (traction on) and 98 against 248 (traction off, numpy, one
    # right-hand side); the full SIMPLE matrix solved per iteration would give 66 / 42 for a
    # pressure Poisson solve in every preconditioner call, not kept. Measured on the runs
    # (2026-12-02, 2 cores): bore flow 280 / 440 outer iterations at 4 / 6 per radius against
    # 440 / 720, same profile, solve 2.1-2.5x faster, but 2,760 against 1,160 at 8 per radius
    # (SIMPLE's error in the interior grows with the resolution; the geometric mean of the two
    # diagonals took 240 / 400 / 600 there and 47 a step on the bead: measured, not landed);
    # the bundled bead at draft without the traction 47 outer / 249 inner iterations a step
    # against 90 / 461 (157-277 s against 376 s with compilation, which varies with Taichi's
    # kernel cache), same section; with the traction 80-91 outer iterations a step against
    # 140-250 while the melt grows to 352 particles (then see "Free surface" above).
    @ti.func
    def _pressure_task(self, i, slot, j, xij, acc: ti.template()):
        """G(k)_i of z's k."""
        gV = self.VF[i, slot] * xij
        acc += self._pressure_pair(i, j, gV, self._corrected(i, gV))

    @ti.func
    def _dt_pressure(self, i):
        """dt G(k)_i of z's k."""
        g = ti.Vector([0.0, 0.0, 0.0], ti.f64)
        self.grid.for_each_listed(i, self._pressure_task, g)
        return self.dt[None] * g

    @ti.func
    def _inner_task(self, i, slot, j, xij, acc: ti.template()):
        """sum_j c F ((p_i - p_j) . x) x, walls as p_j = -p_i (ghost) or 0 (prescribed melt):
        a wall's p is held at zero and its factor is in cF_in, so no branch on the phase."""
        d = self._pair(self.cF_in[i, slot], self.cg_p[i] - self.cg_p[j], ti.cast(xij, ti.f32))
        acc += ti.cast(d, ti.f64)

    @ti.kernel
    def _inner_begin(self, n: ti.i32, j: ti.i32, norm: ti.f64, max_it: ti.i32, S: ti.template(),
                     energy: ti.template()) -> ti.i32:
        """v_j = w / norm (stored here: a launch fewer an iteration); z_k = -sigma v_k; the
        inner solve's right-hand side e = v_u - dt G(z_k) (from T v_j with the criterion's
        norm), x = 0, r = e, cg_z = B^-1 r, p = 0, rz = rz0 = r . B^-1 r; returns whether it
        has stopped already (rz = 0, or no iteration allowed)."""
        self._store_rows(n, j, norm, S)
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            v = self.basis[j, slot]
            self.kpart[i] = -self.sigma[i] * v[3]
            self.z[i] = ti.Vector([0.0, 0.0, 0.0, self.kpart[i]])
        # with reuse the loop reads only its own row, else its neighbours' k (a pair pass)
        ti.loop_config(serialize=S > self.begin_serial)
        for slot in range(n):
            i = self.rows.index[slot]
            v = self.basis[j, slot]
            vu = ti.Vector([v[0], v[1], v[2]])
            r = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            if ti.static(self.reuse):
                t = self.tb[j, slot]
                r = self.Bm[slot] @ ti.Vector([t[0], t[1], t[2]])
                self.cg_g[slot] = vu - r
            else:
                r = vu - self._dt_pressure(i)
            self.cg_x[slot] = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            self.cg_r[slot] = r
            self.cg_z[slot] = self._inner_block(i, slot, energy) @ r
            self.cg_p[i] = ti.Vector.zero(ti.f32, 3)
        self._inner_blocks(n, 0, S, energy)
        ti.loop_config(serialize=True)
        for _ in range(1):
            rz = self.total[None]
            self.cg_rz[None] = rz
            self.cg_rz0[None] = rz
            self.cg_beta[None] = 0.0
            self.cg_it[None] = 0
            self.cg_done[None] = 0 if (rz > 0.0 and max_it > 0) else 1
        return self.cg_done[None]

    @ti.func
    def _direction(self, i, energy: ti.template()):
        """The inner solve's search direction p at row i: in z's velocity on the strain-energy
        form (its operator reads z), in the f32 cg_p on Weiler's sum."""
        out = ti.Vector.zero(ti.f64, 3)
        if ti.static(energy):
            zi = self.z[i]
            out = ti.Vector([zi[0], zi[1], zi[2]])
        else:
            out = ti.cast(self.cg_p[i], ti.f64)
        return out

    @ti.func
    def _inner_block(self, i, slot, energy: ti.template()):
        """The inner solve's preconditioner: the diagonal block of the operator it inverts,
        the strain-energy form's (energy) or Weiler's sum's."""
        out = ti.Matrix.zero(ti.f64, 3, 3)
        if ti.static(energy):
            out = self.Binv[i]
        else:
            out = self.Binv_in[slot]
        return out

    @ti.func
    def _inner_blocks(self, n, which, S: ti.template(), energy: ti.template()):
        """r . cg_z (which 0) or p . q (which 1): block by block, then the blocks in order."""
        nb = (n + self.block - 1) // self.block
        ti.loop_config(serialize=S > 0)
        for b in range(nb):
            s = ti.cast(0.0, ti.f64)
            for slot in range(b * self.block, ti.min((b + 1) * self.block, n)):
                i = self.rows.index[slot]
                if which == 0:
                    s += self.cg_r[slot].dot(self.cg_z[slot])
                else:
                    s += self._direction(i, energy).dot(self.cg_q[slot])
            self.cg_part[which, b] = s
        return self._in_order(self.cg_part, which, nb)

    @ti.func
    def _in_order(self, part: ti.template(), row, nb):
        """sum_b part[row, b] in block order, the same sum on every run, on any device (the
        host's to_numpy of the partials cost 0.34 ms a call, a third of the bead's solve)."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            s = ti.cast(0.0, ti.f64)
            for b in range(nb):
                s += part[row, b]
            self.total[None] = s
        return self.total[None]

    @ti.kernel
    def _inner_iterations(self, n: ti.i32, tol2: ti.f64, max_it: ti.i32, S: ti.template()) -> ti.i32:
        """``cg_chunk`` conjugate-gradient iterations in one launch (a launch and a wait cost
        about as much as the sums on a bead's few thousand rows; iterations after the stop do
        no work), each: p = cg_z + beta p, q = A~ p, alpha = rz / p.q, x += alpha p,
        r -= alpha q, cg_z = B^-1 r, beta = rz_new / rz. The stop: r . cg_z at most tol2 times
        its start, or max_it iterations, or p . q <= 0 (rounding at convergence: A~ is
        positive definite), which leaves x and r alone. Returns whether it has stopped."""
        for _step in ti.static(range(self.chunk)):
            ti.loop_config(serialize=S > 0)
            for slot in range(n):
                if self.cg_done[None] == 0:
                    i = self.rows.index[slot]
                    self.cg_p[i] = ti.cast(self.cg_z[slot] + self.cg_beta[None] * self.cg_p[i], ti.f32)
            ti.loop_config(serialize=S > 1)
            for slot in range(n):
                if self.cg_done[None] == 0:
                    i = self.rows.index[slot]
                    acc = ti.Vector([0.0, 0.0, 0.0], ti.f64)
                    self.grid.for_each_listed(i, self._inner_task, acc)
                    self.cg_q[slot] = ti.cast(self.cg_p[i], ti.f64) - self.dt[None] * acc
            self._inner_step(n, tol2, max_it, S, False)
        return self.cg_done[None]

    @ti.kernel
    def _inner_iteration_energy(self, n: ti.i32, tol2: ti.f64, max_it: ti.i32,
                                S: ti.template()) -> ti.i32:
        """One inner iteration on the strain-energy form's momentum block (with the surface
        traction), the system's own viscous operator: q = p - dt L(p), L with Adami's ghosts
        and the hourglass term as _apply has them (its four passes over the melt: one launch
        an iteration, so that none is spent after the stop). z carries p's velocity meanwhile;
        _inner_finish puts z back."""
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            p = self.cg_z[slot] + self.cg_beta[None] * self._direction(i, True)
            self.z[i] = ti.Vector([p[0], p[1], p[2], 0.0])
        self._viscous_of_z(n, S)
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            self.cg_q[slot] = self._direction(i, True) - self.dt[None] * self.eacc[i]
        self._inner_step(n, tol2, max_it, S, True)
        return self.cg_done[None]

    @ti.func
    def _inner_step(self, n, tol2, max_it, S: ti.template(), energy: ti.template()):
        """The rest of an inner iteration once q = A~ p: alpha, x, r, z, beta and the stop."""
        self._inner_blocks(n, 1, S, energy)
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.cg_done[None] == 0:
                pq = self.total[None]
                if pq > 0.0:
                    self.alpha[None] = self.cg_rz[None] / pq
                else:
                    self.cg_done[None] = 1
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            if self.cg_done[None] == 0:
                i = self.rows.index[slot]
                alpha = self.alpha[None]
                self.cg_x[slot] += alpha * self._direction(i, energy)
                r = self.cg_r[slot] - alpha * self.cg_q[slot]
                self.cg_r[slot] = r
                self.cg_z[slot] = self._inner_block(i, slot, energy) @ r
        self._inner_blocks(n, 0, S, energy)
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.cg_done[None] == 0:
                rz, rz_old = self.total[None], self.cg_rz[None]
                self.cg_rz[None] = rz
                self.cg_beta[None] = rz / rz_old
                self.cg_it[None] += 1
                if not (rz > 0.0 and self.cg_it[None] < max_it and rz > tol2 * self.cg_rz0[None]):
                    self.cg_done[None] = 1

    @ti.kernel
    def _inner_finish(self, n: ti.i32, j: ti.i32, S: ti.template()):
        """z = (x, k), kept as Z_j; w = A z; with the criterion's norm T w (one launch)."""
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            x = self.cg_x[slot]
            z = ti.Vector([x[0], x[1], x[2], self.kpart[i]])
            self.z[i] = z
            self.Zb[j, slot] = z
        self._apply(n, self.w, S, not self.reuse)
        if ti.static(self.exact):
            self._t_of_w(n, S)

    def _block_triangular(self, n: int, j: int, norm: float, S: bool) -> int:
        """v_j = w / norm; w = A P^-1 v_j, P^-1 v_j kept in Z_j (conjugate gradients on A~
        with the 3 x 3 diagonal blocks as preconditioner, from zero, to inner_tolerance), and
        T w with the criterion's norm; returns the inner iterations."""
        tol2 = self.inner_tol ** 2
        done = self._inner_begin(n, j, norm, self.inner_max, S, self.inner_energy)
        while not done:
            if self.inner_energy:
                done = self._inner_iteration_energy(n, tol2, self.inner_max, S)
            else:
                done = self._inner_iterations(n, tol2, self.inner_max, S)
        self._inner_finish(n, j, S)
        return int(self.cg_it[None])

    # ------------------------------------------------------------------ kernels
    @ti.kernel
    def _setup(self, n: ti.i32, n_all: ti.i32, dt: ti.f64, gx: ti.f64, gy: ti.f64, gz: ti.f64,
               ax: ti.f64, ay: ti.f64, az: ti.f64, a_above: ti.f64,
               kappa: ti.template(), S: ti.template()):
        """Walls near the melt and their Shepard sums; per-pair coefficients; preconditioner;
        right-hand side (v* = v_n + dt g, plus dt a above the drive's plane, plus the walls'
        constant terms; the continuity rows with k_n = kappa's). n_all: the live particles,
        an argument: a Python number read inside a kernel is a constant of its compilation
        (state.n read here was the count at the first solve, so walls sorted past it were left
        out of every later solve)."""
        self.dt[None] = dt
        ti.loop_config(serialize=S > 0)
        for i in range(n_all):
            self.shepard[i] = 0.0
            self.ghost[i] = ti.Vector.zero(ti.f64, 3)
            self.z[i] = ti.Vector.zero(ti.f64, 4)
            if ti.static(self.flexible):
                if self.state.phase[i] != FLUID:
                    self.cg_p[i] = ti.Vector.zero(ti.f32, 3)
        ti.loop_config(serialize=True)  # in storage order: every launch sums in the same order
        for _ in range(1):
            self.n_walls[None] = 0
            for b in range(n_all):
                ph = self.state.phase[b]
                # the bore's melt column is melt at a prescribed velocity, not a wall: it
                # takes no ghost (u_b = v_b)
                if ph != FLUID and ph != INLET and (ph == SOLID or self.grid.wall_needed[b] == 1):
                    self.wall_row[self.n_walls[None]] = b
                    self.n_walls[None] += 1
        ti.loop_config(serialize=S > 1)
        for wslot in range(self.n_walls[None]):
            b = self.wall_row[wslot]
            s = 0.0
            self.grid.for_each_neighbour(b, self._shepard_task, s)
            self.shepard[b] = s
        # only walls with melt in reach take part: every solidified particle is a candidate,
        # and a window's substrate (17,788 on benchy's 4 x 4 mm window, against 576 melt
        # rows) made the ghosts' grid scans in every application of the operator most of the
        # solve. A wall no melt row reaches has a zero Shepard sum, no ghost that any row
        # reads and no share in a melt row's sums: leaving it out changes nothing.
        ti.loop_config(serialize=True)  # in order, in place
        for _ in range(1):
            kept = 0
            for wslot in range(self.n_walls[None]):
                b = self.wall_row[wslot]
                if self.shepard[b] > 0.0:
                    self.wall_row[kept] = b
                    kept += 1
            self.n_walls[None] = kept
        if ti.static(self.traction):
            self._surface_setup(n, S)
            # the viscous term's constant part: L of zero melt velocities, walls at theirs
            self.affine[None] = 1
            self._energy(n, S)
            self.affine[None] = 0
            ti.loop_config(serialize=S > 0)
            for slot in range(n):
                i = self.rows.index[slot]
                self.surf_rhs[i] = self.eacc[i]
        if ti.static(self.quadratic):
            self._fit_setup(n, S)
        if ti.static(self.surface_rows):
            ti.loop_config(serialize=S > 1)
            for slot in range(n):
                i = self.rows.index[slot]
                self.srow[i] = 0
                self.sq[i] = ti.Vector.zero(ti.f64, 3)
                nrm = ti.cast(self.surface.normal[i], ti.f64)
                if self.surface.flag[i] == 1 and nrm.norm() > 0.5:
                    nu = ti.cast(self.visc.eta_of(i), ti.f64) / self.rho0
                    self.srow[i] = 1
                    self.sn[i] = nrm
                    # only the surface rows need M^-1 (the strain-energy form keeps every row's)
                    self.sq[i] = 2.0 * nu * (self._moment_inverse(i).transpose() @ nrm)
        g = ti.Vector([gx, gy, gz])
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            acc = ti.Vector.zero(ti.f64, 14)
            self.grid.for_each_listed(i, self._setup_task, acc)
            if ti.static(self.surface_rows):
                self.s_rhs[i] = acc[13]
            sq = self._square(acc, 0)  # Weiler's sum's diagonal block
            b = ti.Matrix.identity(ti.f64, 3) - dt * sq  # B on Weiler's rows (the form's below)
            weiler = b.inverse()
            self.Binv_in[slot] = weiler
            v = ti.cast(self.state.v[i], ti.f64) + dt * g
            if self.state.x[i][2] > a_above:
                v += dt * ti.Vector([ax, ay, az])
            mom = v
            if ti.static(self.traction):
                mom += dt * self.surf_rhs[i]
                e = ti.Vector.zero(ti.f64, 12)
                self.grid.for_each_listed(i, self._energy_block_task, e)
                a = -ti.Vector([e[0], e[1], e[2]])
                nu = ti.cast(self.visc.eta_of(i), ti.f64) / self.rho0
                # the hourglass term's pair part: Weiler's block scaled by its weight
                blk = self._square(e, 3) + nu * (a.norm_sqr() * ti.Matrix.identity(ti.f64, 3)
                                                 + a.outer_product(a)) \
                    - self.hourglass * sq
                b = ti.Matrix.identity(ti.f64, 3) + dt * blk
                self.Binv[i] = b.inverse()
            else:
                self.Binv[i] = weiler
                mom -= dt * ti.Vector([acc[9], acc[10], acc[11]])
            if ti.static(self.reuse):
                self.Bm[slot] = b
            # the melt's compressibility: dt D(u) - (k - k_n) / c^2 = dt s
            kn = ti.cast(kappa[i], ti.f64)
            s = -self.c2inv[None] / dt * kn
            if ti.static(self.summation_source):
                # the kernel sum's compression less the elastic part k_n / c^2 that k_n
                # already holds: counted twice, the pressure of a compression no flow could
                # relieve grew by c^2 times it every step
                rho = ti.cast(self.state.rho[i], ti.f64) / self.rho0
                error = (1.0 + self.c2inv[None] * kn - rho) / dt
                if ti.static(self.two_way):
                    # a full kernel's sum short of rho0 is expansion, not a missing
                    # neighbour; full is Marrone's interior bound on the eigenvalue, not his
                    # umbrella: a covered particle with lambda <= 0.75 sits at a hole (melt
                    # torn as the nozzle's rim passes), which this row would close in one step
                    full = self.surface.flag[i] == 0 and self.surface.lam[i] > 0.75
                    s += error if full else ti.min(error, 0.0)
                else:
                    s += ti.min(error, 0.0)
            self.rhs[i] = ti.Vector([mom[0], mom[1], mom[2], self.dx * (s + acc[12])])
        # the Schur approximation needs every melt row's B^-1: a loop of its own
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            acc = ti.Vector.zero(ti.f64, 4)
            self.grid.for_each_listed(i, self._schur_task, acc)
            Gi = ti.Vector([acc[0], acc[1], acc[2]])
            # (D B^-1 G)_ii; the dx-scaled continuity rows and dt G make it dx dt times that
            s_ii = (self.Binv[i] @ Gi).dot(Gi) + acc[3]
            s_ii = dt * self.dx * s_ii + self.dx * self.c2inv[None] / dt
            self.sigma[i] = 1.0 / s_ii if s_ii > 0.0 else 0.0
            if ti.static(self.surface_rows):
                # the row s_ii (k - 2 nu n.D.n) = 0: a pressure error weighs in it as in a
                # continuity row, so the Schur preconditioner and the stop read it alike
                if self.srow[i] == 1:
                    if s_ii > 0.0:
                        r = self.rhs[i]
                        self.rhs[i] = ti.Vector([r[0], r[1], r[2], s_ii * self.s_rhs[i]])
                    else:
                        self.srow[i] = 0

    @ti.func
    def _pressure_error(self, n, S: ti.template()):
        """z's k = -sigma w_k: the pressure error the continuity residual leaves, as the
        preconditioner reads it (see "Tolerance")."""
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            self.z[i] = ti.Vector([0.0, 0.0, 0.0, -self.sigma[i] * self.w[slot][3]])

    @ti.func
    def _velocity_error(self, i, slot):
        """w_u - dt G(-sigma w_k) at row i (after _pressure_error): the velocity error the
        residual stands for; B^-1 of it is the stop's measure."""
        wi = self.w[slot]
        return ti.Vector([wi[0], wi[1], wi[2]]) - self._dt_pressure(i)

    @ti.kernel
    def _criterion(self, n: ti.i32, S: ti.template()) -> ti.f64:
        """T w (_t_of_w); returns |T w|^2."""
        self._t_of_w(n, S)
        return self._w_sum(n, False, S)

    @ti.func
    def _t_of_w(self, n, S: ti.template()):
        """tw = T w = (B^-1 (w_u - dt G(-sigma w_k)), c w_k): the velocity error w stands for
        and its density error on the same scale (see "Norm")."""
        self._pressure_error(n, S)
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            e = self.Binv[i] @ self._velocity_error(i, slot)
            self.tw[slot] = ti.Vector([e[0], e[1], e[2], self.crho[None] * self.w[slot][3]])

    @ti.kernel
    def _residual(self, n: ti.i32, S: ti.template()) -> ti.types.vector(3, ti.f64):
        """w = rhs - A X (z = X: X is kept unpreconditioned); returns (|B^-1 (w_u - dt G(dk))|^2
        with dk = -sigma w_k, and |B^-1 rhs|^2, over the momentum rows; largest |continuity
        residual| as a density error dt |D(u) - s|). B^-1 (the diagonal blocks' inverse) turns
        both into velocities: the right-hand side is dominated by the walls' terms, ~ nu dt /
        dx^2 times the wall speed, so an unscaled relative residual of 1e-6 let velocities be
        wrong by their own size. dk is the pressure error the continuity residual leaves, as
        the preconditioner reads it; dt G(dk) the velocity it would move."""
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            self.z[i] = self.X[i]
        self._apply(n, self.w, S, True)
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            self.w[slot] = self.rhs[i] - self.w[slot]
        self._pressure_error(n, S)
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            self.werr[i] = self._velocity_error(i, slot)
        return self._norms(n, S)

    @ti.func
    def _norms(self, n, S: ti.template()):
        nb = (n + self.block - 1) // self.block
        ti.loop_config(serialize=S > 0)
        for b in range(nb):
            su = ti.cast(0.0, ti.f64)
            sb = ti.cast(0.0, ti.f64)
            sm = ti.cast(0.0, ti.f64)
            for slot in range(b * self.block, ti.min((b + 1) * self.block, n)):
                i = self.rows.index[slot]
                wi = self.w[slot]
                ri = self.rhs[i]
                zw = self.Binv[i] @ self.werr[i]
                zr = self.Binv[i] @ ti.Vector([ri[0], ri[1], ri[2]])
                su += zw.norm_sqr()
                sb += zr.norm_sqr()
                sm = ti.max(sm, ti.abs(wi[3]))
            self.part[0, b] = su
            self.part[1, b] = sb
            self.part[2, b] = sm
        ti.loop_config(serialize=True)
        for _ in range(1):
            out = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            for b in range(nb):
                out[0] += self.part[0, b]
                out[1] += self.part[1, b]
                out[2] = ti.max(out[2], self.part[2, b])
            self.out3[None] = ti.Vector([out[0], out[1], out[2] * self.dt[None] / self.dx])
        return self.out3[None]

    @ti.kernel
    def _arnoldi_apply(self, n: ti.i32, j: ti.i32, norm: ti.f64, S: ti.template()):
        """v_j = w / norm; w = A M^-1 v_j; with the criterion's norm T w (one launch)."""
        self._store_rows(n, j, norm, S)
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            self.w[slot] = self.basis[j, slot]
        self._precondition(n, self.w, S)
        self._apply(n, self.w, S, True)
        if ti.static(self.exact):
            self._t_of_w(n, S)

    @ti.kernel
    def _gram_schmidt(self, n: ti.i32, j: ti.i32, out: ti.types.ndarray(dtype=ti.f64, ndim=1), S: ti.template()) -> ti.f64:
        """Classical Gram-Schmidt, gs_passes passes in one launch (see "Orthogonalisation"),
        each: c_l = v_l . w for l = 0..j (block by block, then the blocks in order),
        w -= sum_l c_l v_l; out_l = the passes' c_l summed (H's column); returns |w|^2."""
        for gs_pass in ti.static(range(self.gs_passes)):
            self._gram_schmidt_pass(n, j, out, gs_pass, S)
        return self._w_sum(n, False, S)

    @ti.func
    def _gram_schmidt_pass(self, n, j, out: ti.template(), gs_pass: ti.template(), S: ti.template()):
        nb = (n + self.block - 1) // self.block
        ti.loop_config(serialize=S > 1)
        for l, b in ti.ndrange(j + 1, nb):
            s = ti.cast(0.0, ti.f64)
            for slot in range(b * self.block, ti.min((b + 1) * self.block, n)):
                if ti.static(self.exact):
                    s += self.tb[l, slot].dot(self.tw[slot])
                else:
                    s += self.basis[l, slot].dot(self.w[slot])
            self.part[l, b] = s
        ti.loop_config(serialize=True)
        for l in range(j + 1):
            s = ti.cast(0.0, ti.f64)
            for b in range(nb):
                s += self.part[l, b]
            self.coef[l] = s
            if ti.static(gs_pass == 0):
                out[l] = s
            else:
                out[l] += s
        self._orthogonalise(n, j, S)

    @ti.func
    def _orthogonalise(self, n, j, S: ti.template()):
        """w -= sum_l coef_l v_l."""
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            acc = self.w[slot]
            for l in range(j + 1):
                acc -= self.coef[l] * self.basis[l, slot]
            self.w[slot] = acc
            if ti.static(self.exact):  # T is linear: T w follows w without another T
                t = self.tw[slot]
                for l in range(j + 1):
                    t -= self.coef[l] * self.tb[l, slot]
                self.tw[slot] = t

    @ti.func
    def _store_rows(self, n, j, norm, S: ti.template()):
        """v_j = w / norm (and T v_j = T w / norm)."""
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            self.basis[j, slot] = self.w[slot] / norm
            if ti.static(self.exact):
                self.tb[j, slot] = self.tw[slot] / norm

    @ti.func
    def _combine(self, n, k, vectors: ti.template(), S: ti.template()):
        """w = sum_l coef_l vectors_l."""
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            acc = ti.Vector.zero(ti.f64, 4)
            for l in range(k):
                acc += self.coef[l] * vectors[l, slot]
            self.w[slot] = acc

    @ti.kernel
    def _update(self, n: ti.i32, k: ti.i32, flexible: ti.template(), S: ti.template()):
        """X += sum_l coef_l Z_l (flexible GMRES keeps the preconditioned vectors), or
        X += M^-1 (sum_l coef_l v_l)."""
        if ti.static(flexible):
            self._combine(n, k, self.Zb, S)
        else:
            self._combine(n, k, self.basis, S)
            self._precondition(n, self.w, S)
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            self.X[i] += self.w[slot] if ti.static(flexible) else self.z[i]

    @ti.kernel
    def _warm(self, n: ti.i32, n_all: ti.i32, kappa: ti.template(), from_state: ti.i32,
              ratio: ti.f64, S: ti.template()):
        """X0: the melt's velocity extrapolated from its last two steps, v_n + ratio (v_n -
        v_n-1) (ratio = dt / dt_n-1; 0: v_n), and, where given, last step's k; then v_n
        becomes every particle's previous velocity."""
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            v = ti.cast(self.state.v[i], ti.f64)
            if ti.static(self.extrapolated):
                v += ratio * (v - ti.cast(self.v_prev[i], ti.f64))
            k = ti.select(from_state == 1, ti.cast(kappa[i], ti.f64), 0.0)
            self.X[i] = ti.Vector([v[0], v[1], v[2], k])
        if ti.static(self.extrapolated):
            for i in range(n_all):
                self.v_prev[i] = self.state.v[i]

    @ti.kernel
    def _start_history(self, lo: ti.i32, hi: ti.i32):
        for i in range(lo, hi):
            self.v_prev[i] = self.state.v[i]

    def _appended(self, sl: slice, phase: int) -> None:
        """Particles entering the domain start their history at their own velocity."""
        self._start_history(sl.start, sl.stop)

    def forget_history(self) -> None:
        """The melt's velocities were set from outside the solve (an idle span zeroed them):
        the next solve starts from them, not from an extrapolation."""
        self.previous_dt = 0.0

    @ti.kernel
    def _finish(self, n: ti.i32, kappa: ti.template(), S: ti.template()):
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            x = self.X[i]
            # the state's precision (f32 by default): the solve's f64 is for its sums
            self.state.v[i] = ti.Vector([ti.cast(x[0], float), ti.cast(x[1], float),
                                         ti.cast(x[2], float)])
            kappa[i] = ti.cast(x[3], float)

    def _set_coef(self, values: np.ndarray) -> None:
        buf = np.zeros(self.m + 1)
        buf[: len(values)] = values
        self.coef.from_numpy(buf)

    def serial(self, n: int) -> int:
        """How a solve over n rows runs its loops, a template argument of every kernel here
        (each choice is compiled once): 2, every loop on the calling thread; 1, the loops over
        neighbours in parallel and the rest (streams over a row's own vectors) on the calling
        thread; 0, every loop in parallel (a GPU). A parallel loop costs a hand-off to the
        thread pool, 0.05-0.07 ms on 2 cores, the time a stream over 50,000 rows takes on
        one thread, while a loop over the neighbours of a few thousand rows takes tenths of
        a millisecond (the solve gains from two threads from about 4,000 rows: see the options).
        Every loop writes its own rows and every sum goes block by block in a fixed order, so
        the choices differ only in how the compiler arranged each loop's arithmetic (fast
        math's contractions): on the film the same iterations and velocities 2e-8 of the
        fastest apart (test), the same iteration counts on the bundled bead, not on benchy's
        window (32.4 against 32.9 GMRES iterations a step over 691 steps, both converged)."""
        if not self.on_cpu:
            return 0
        if n < self.pair_rows:
            return 2
        return 1 if n < self.serial_rows else 0

    # ------------------------------------------------------------------ public
    def attach_surface(self, surface) -> None:
        """The free-surface detector (physics/surface.py) whose flags tell the two-way source
        which particles have a full kernel; a solve refreshes them once per rebuild of the
        neighbour lists (SurfaceDetector.current), the heat's areas sharing that update."""
        self.surface = surface

    def solve(self, dt: float, kappa, gravity_m_s2=(0.0, 0.0, 0.0),
              warm_pressure: bool = True, compressible: bool = True,
              extrapolate: bool = True) -> StokesResult:
        """Replace the melt's velocities by the step's solution and write k into ``kappa``
        (a per-particle field: k = p / rho0, m^2/s^2). The caller has sorted the particles,
        built the neighbour lists, updated ``rows`` and set the densities. compressible=False:
        incompressible rows whatever the option (a quasi-static solve: a steady state).
        extrapolate=False: start from v_n, and void the history (a solve that is no step)."""
        n = self.rows.n
        if n > self.rows_cap:
            raise RuntimeError(f"{n} melt rows exceed the {self.rows_cap} the coupled solve was "
                               "sized for: only the inlet makes melt, and the plan counts it")
        self.c2inv[None] = self.inv_c2 if compressible else 0.0
        if self.surface_rows or self.two_way:
            if self.surface is None:
                raise RuntimeError("the two-way density source and the free-surface rows read "
                                   "the free-surface flags: attach_surface() before the first "
                                   "solve")
            self.surface.current()
        inner = 0
        S = self.serial(n)
        self._setup(n, self.state.n, float(dt), *map(float, gravity_m_s2), *self.drive, kappa, S)
        ratio = 0.0
        if self.extrapolated and extrapolate and self.previous_dt > 0.0:
            ratio = float(dt) / self.previous_dt
        self._warm(n, self.state.n, kappa, 1 if warm_pressure else 0, ratio, S)
        self.previous_dt = float(dt) if extrapolate else 0.0
        free = self._find_free(n, S)
        iterations = 0
        sweeps = 0  # Gram-Schmidt's passes over earlier Krylov vectors, all iterations together
        m = self.m
        while True:
            if free:
                self._rigid(n, S)
            ru, rb, rmax = self._residual(n, S).to_numpy()
            rel = (ru / rb) ** 0.5 if rb > 0.0 else ru ** 0.5
            if self.exact:
                # T's density weight: a density error at its tolerance weighs as a velocity
                # error at its own on the criterion's scale |B^-1 rhs| (fixed within a solve)
                scale = float(dt) / self.dx * self.tol_u * float(np.sqrt(rb if rb > 0.0 else 1.0))
                self.crho[None] = scale / self.tol_rho
            done = rel <= self.tol_u and rmax <= self.tol_rho
            if self.exact:
                beta = float(np.sqrt(self._criterion(n, S)))  # |T w|: the Krylov space's start
            else:
                beta = float(np.sqrt(self._sum(n, False, S)))  # |w|
            log.debug("coupled solve: %d iterations, momentum %.3g, density %.3g, |w| %.3g",
                      iterations, rel, rmax, beta)
            if done or iterations >= self.max_iterations or beta == 0.0:
                break  # w holds the residual of X: the result is read from it below
            norm = beta  # v_j = w / norm, stored by the launch that multiplies by v_j
            H = np.zeros((m + 1, m))
            cs, sn = np.zeros(m), np.zeros(m)
            g = np.zeros(m + 1)
            g[0] = beta
            k = 0
            for j in range(m):
                if self.flexible:
                    inner += self._block_triangular(n, j, norm, S)
                else:
                    self._arnoldi_apply(n, j, norm, S)
                h = np.zeros(j + 2)
                norm2 = self._gram_schmidt(n, j, self.dots_out, S)
                h[: j + 1] = self.dots_out[: j + 1]
                h[j + 1] = norm = breakdown = float(np.sqrt(norm2))
                for l in range(j):  # earlier Givens rotations
                    a, b = h[l], h[l + 1]
                    h[l], h[l + 1] = cs[l] * a + sn[l] * b, -sn[l] * a + cs[l] * b
                denom = float(np.hypot(h[j], h[j + 1]))
                cs[j], sn[j] = (h[j] / denom, h[j + 1] / denom) if denom > 0 else (1.0, 0.0)
                h[j], h[j + 1] = denom, 0.0
                g[j + 1] = -sn[j] * g[j]
                g[j] = cs[j] * g[j]
                H[: j + 2, j] = h
                k = j + 1
                iterations += 1
                sweeps += (j + 1) * self.gs_passes
                # |g[j + 1]| is the iterate's residual norm (right preconditioning): end the
                # cycle once the criteria, scaled by how far it fell since the cycle began,
                # are met; the true residuals decide at the top of the loop (a cycle that
                # stopped too early is followed by another)
                fall = abs(g[j + 1]) / beta
                if (iterations >= self.max_iterations or breakdown == 0.0
                        or (rel * fall <= self.tol_u and rmax * fall <= self.tol_rho)):
                    break
            y = np.linalg.solve(np.triu(H[:k, :k]), g[:k]) if k else np.zeros(0)
            self._set_coef(y)
            self._update(n, k, self.flexible, S)
        mean = self._sum(n, True, S) / max(n, 1)
        self._finish(n, kappa, S)
        if self.flexible:
            self._choose_inner(iterations, inner, sweeps)
        return StokesResult(bool(done), iterations, float(rel), float(rmax), mean, inner, free_rows=free)

    def _choose_inner(self, iterations: int, inner: int, sweeps: int = 0):
        """Count this solve's work against the inner operator it used and, with 'auto', pick
        the next solve's (see "block-triangular preconditioner"): an operator not yet tried,
        or the one whose latest solve cost fewer passes over the melt's neighbour lists, or,
        once the one in use costs twice what it did when the two were last compared, the
        other again (its count is stale). Counts, not timings: a run makes the same choices
        every time."""
        used = self.inner_energy
        work = (OUTER_PASSES * iterations + (ENERGY_INNER_PASSES if used else 1) * inner
                + KRYLOV_SWEEP_PASSES * sweeps)
        self.inner_solves[used] += 1
        if work == 0:
            return  # solved from its start: no count of either operator
        self.inner_work[used] = work
        if self.inner_ref[used] is None:
            self.inner_ref[used] = work
        log.debug("coupled solve: inner operator %s, %d GMRES / %d inner iterations, %.0f passes",
                  "system" if used else "weiler2018", iterations, inner, work)
        if not self.inner_auto:
            return
        other = self.inner_work[not used]
        if other is None or other < work or work > 2 * self.inner_ref[used]:
            self.inner_energy = not used
            self.inner_ref[not used] = None  # its first solve now sets its reference

    @ti.kernel
    def _block_sums(self, n: ti.i32, continuity: ti.template(), S: ti.template()) -> ti.f64:
        return self._w_sum(n, continuity, S)

    @ti.func
    def _w_sum(self, n, continuity: ti.template(), S: ti.template()):
        """sum of |w|^2, or of |w_k| (the continuity rows): block by block, then in order."""
        nb = (n + self.block - 1) // self.block
        ti.loop_config(serialize=S > 0)
        for b in range(nb):
            s = ti.cast(0.0, ti.f64)
            for slot in range(b * self.block, ti.min((b + 1) * self.block, n)):
                if ti.static(continuity):
                    s += ti.abs(self.w[slot][3])
                elif ti.static(self.exact):
                    s += self.tw[slot].norm_sqr()
                else:
                    s += self.w[slot].norm_sqr()
            self.part[0, b] = s
        return self._in_order(self.part, 0, nb)

    def _sum(self, n: int, continuity: bool, S: bool) -> float:
        return float(self._block_sums(n, continuity, S))

    # ------------------------------------------------------------------ free fragments
    @ti.func
    def _anchor_task(self, i, j, xij, acc: ti.template()):
        if self.state.phase[j] != FLUID or self.anchored[j] == 1:
            acc += 1

    @ti.kernel
    def _free_begin(self, n: ti.i32, S: ti.template()):
        """No melt row anchored yet, each its own label."""
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            self.anchored[i] = 0
            self.comp[i] = i

    @ti.kernel
    def _free_spread(self, n: ti.i32, S: ti.template()) -> ti.i32:
        """A melt row with a wall (or the bore's prescribed column) or an anchored melt row
        within H is anchored; returns how many rows this pass anchored (the set the passes
        converge to does not depend on the order)."""
        self.changed[None] = 0
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            if self.anchored[i] == 0:
                acc = 0
                self.grid.for_each_neighbour(i, self._anchor_task, acc)
                if acc > 0:
                    self.anchored[i] = 1
                    ti.atomic_add(self.changed[None], 1)
        return self.changed[None]

    @ti.func
    def _label_task(self, i, j, xij, acc: ti.template()):
        acc = ti.min(acc, self.comp[j])

    @ti.kernel
    def _free_label(self, n: ti.i32, S: ti.template()) -> ti.i32:
        """Each free row takes the smallest label among its melt neighbours, then its
        label's label; returns how many changed (each fragment ends on its smallest index)."""
        self.changed[None] = 0
        ti.loop_config(serialize=S > 1)
        for slot in range(n):
            i = self.rows.index[slot]
            if self.anchored[i] == 0:
                m = self.comp[i]
                self.grid.for_each_neighbour(i, self._label_task, m)
                m = self.comp[m]
                if m < self.comp[i]:
                    self.comp[i] = m
                    ti.atomic_add(self.changed[None], 1)
        return self.changed[None]

    @ti.kernel
    def _free_geometry(self, n: ti.i32):
        """Per fragment: size, centroid and the inverse of its inertia sum(|r|^2 I - r r^T)
        (shifted by 1e-9 of its trace: a line of particles has no inertia about itself, and
        no residual moment about that axis either; a single particle no rotation). In order,
        one thread: the fragments are few, and their sums then round the same on every run."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            for slot in range(n):
                i = self.rows.index[slot]
                if self.anchored[i] == 0 and self.comp[i] == i:  # a fragment's label is its row
                    self.cl_n[i] = 0.0
                    self.cl_c[i] = ti.Vector.zero(ti.f64, 3)
                    self.cl_Jinv[i] = ti.Matrix.zero(ti.f64, 3, 3)
            for slot in range(n):
                i = self.rows.index[slot]
                if self.anchored[i] == 0:
                    r = self.comp[i]
                    self.cl_n[r] += 1.0
                    self.cl_c[r] += ti.cast(self.state.x[i], ti.f64)
            for slot in range(n):
                i = self.rows.index[slot]
                if self.anchored[i] == 0 and self.comp[i] == i:
                    self.cl_c[i] /= self.cl_n[i]
            for slot in range(n):
                i = self.rows.index[slot]
                if self.anchored[i] == 0:
                    r = self.comp[i]
                    d = ti.cast(self.state.x[i], ti.f64) - self.cl_c[r]
                    self.cl_Jinv[r] += d.norm_sqr() * ti.Matrix.identity(ti.f64, 3) - d.outer_product(d)
            for slot in range(n):
                i = self.rows.index[slot]
                if self.anchored[i] == 0 and self.comp[i] == i:
                    J = self.cl_Jinv[i]
                    tr = J.trace()
                    inv = ti.Matrix.zero(ti.f64, 3, 3)
                    if tr > 0.0:
                        inv = (J + 1e-9 * tr * ti.Matrix.identity(ti.f64, 3)).inverse()
                    self.cl_Jinv[i] = inv

    @ti.kernel
    def _rigid(self, n: ti.i32, S: ti.template()):
        """Set each free fragment's rigid motion to its exact one: the translation and rotation
        that leave its momentum rows' residual with no net force and no net moment."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            for slot in range(n):
                i = self.rows.index[slot]
                if self.anchored[i] == 0 and self.comp[i] == i:
                    self.cl_a[i] = ti.Vector.zero(ti.f64, 3)
                    self.cl_b[i] = ti.Vector.zero(ti.f64, 3)
            for slot in range(n):
                i = self.rows.index[slot]
                if self.anchored[i] == 0:
                    r = self.comp[i]
                    x = self.X[i]
                    f = self.rhs[i]
                    res = ti.Vector([f[0] - x[0], f[1] - x[1], f[2] - x[2]])
                    self.cl_a[r] += res
                    self.cl_b[r] += (ti.cast(self.state.x[i], ti.f64) - self.cl_c[r]).cross(res)
        ti.loop_config(serialize=S > 0)
        for slot in range(n):
            i = self.rows.index[slot]
            if self.anchored[i] == 0:
                r = self.comp[i]
                a = self.cl_a[r] / self.cl_n[r]
                du = a
                if ti.static(not self.isotropic):  # see "Free fragments": central pairs only
                    b = self.cl_Jinv[r] @ self.cl_b[r]
                    du += b.cross(ti.cast(self.state.x[i], ti.f64) - self.cl_c[r])
                self.X[i] += ti.Vector([du[0], du[1], du[2], 0.0])

    def _find_free(self, n: int, S: bool) -> int:
        """Label the melt's free fragments; returns how many melt rows they hold."""
        self._free_begin(n, S)
        anchored = 0
        while anchored < n:
            grown = int(self._free_spread(n, S))
            if grown == 0:
                break
            anchored += grown
        if anchored == n:
            return 0
        while int(self._free_label(n, S)) > 0:
            pass
        self._free_geometry(n)
        return n - anchored

    # ------------------------------------------------------------------ diagnostics
    @ti.kernel
    def _wall_force(self, n: ti.i32, S: ti.template()) -> ti.types.vector(3, ti.f64):
        """-(the force on the flagged walls): the melt's momentum they take."""
        if ti.static(self.traction):
            # the strain-energy form: -dPhi/dv_b = -rho0 V (2 or 1) q_b with the whole
            # strain (walls' velocities in it) of the solution
            ti.loop_config(serialize=S > 0)
            for slot in range(n):
                i = self.rows.index[slot]
                self.z[i] = self.X[i]
            ti.loop_config(serialize=S > 1)
            for wslot in range(self.n_walls[None]):
                b = self.wall_row[wslot]
                acc = ti.Vector([0.0, 0.0, 0.0], ti.f64)
                self.grid.for_each_neighbour(b, self._ghost_task, acc)
                self.ghost[b] = acc
            self.affine[None] = 1
            self._energy(n, S)
            self.affine[None] = 0
        f = ti.Vector([0.0, 0.0, 0.0], ti.f64)
        ti.loop_config(serialize=True)  # a fixed order: the force is reproducible to the bit
        for slot in range(n):
            i = self.rows.index[slot]
            acc = ti.Vector([0.0, 0.0, 0.0], ti.f64)
            self.grid.for_each_listed(i, self._force_task, acc)
            f += ti.cast(self.state.m[i], ti.f64) * acc
        if ti.static(self.traction):
            ti.loop_config(serialize=True)
            for wslot in range(self.n_walls[None]):
                b = self.wall_row[wslot]
                if self.force_flag[b] == 1:
                    twice = 2.0 if self.shepard[b] > 0.0 else 1.0
                    f += self.rho0 * self.V * twice * self.q[b]
        return f

    def wall_force(self, selected: np.ndarray) -> np.ndarray:
        """Force (N) the melt exerts on the walls flagged in ``selected`` (bool per particle
        in storage order), from the last solve's velocities, ghosts and k."""
        flags = np.zeros(self.state.capacity, dtype=np.int32)
        flags[: len(selected)] = selected
        self.force_flag.from_numpy(flags)
        return -self._wall_force(self.rows.n, self.serial(self.rows.n)).to_numpy()

    @ti.func
    def _force_task(self, i, slot, j, xij, acc: ti.template()):
        """Acceleration of melt particle i by the flagged wall particle j."""
        if self.state.phase[j] != FLUID and self.force_flag[j] == 1:
            x = self.X[i]
            ui = ti.Vector([x[0], x[1], x[2]])
            vb = ti.cast(self.state.v[j], ti.f64)
            ub = vb
            if self.shepard[j] > 0.0:
                ub = 2.0 * vb - self.ghost[j] / self.shepard[j]
            if ti.static(self.quadratic):
                if self._fitted(i, j):
                    d = ti.cast(self.state.wall_depth[j], ti.f64)
                    ac = self.fit_AC[i]
                    ub = (1.0 + d * ac[0] - d * d * ac[1]) * vb - d * self.fit_a[i] \
                        + d * d * self.fit_b[i]
            if ti.static(not self.traction):
                acc += self._pair(self.cF[i, slot], ui - ub, xij)
            acc -= x[3] * self._corrected(i, self.V * ti.cast(self.K.F(xij.norm()), ti.f64) * ti.cast(xij, ti.f64))
