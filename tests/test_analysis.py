"""Mesostructure analysis on synthetic frames: lattice beads of known shape in HDF5 files
laid out like a run's particles.h5 (see taichi_mex/output.py)."""

import json
import math

import h5py
import numpy as np
import pytest

from taichi_mex.post import analysis
from taichi_mex.errors import UserInputError

DX = 0.04e-3          # particle spacing (m)
LENGTH = 12 * DX      # beads run along x over this length, centred on x = 0


def lattice_section(u_lo, u_hi, v_lo, v_hi, dx=DX):
    """Cell-centred (y, z) lattice points of a rectangle in the section plane."""
    ys = np.arange(math.floor(u_lo / dx), math.ceil(u_hi / dx)) * dx + dx / 2
    zs = np.arange(math.floor(v_lo / dx), math.ceil(v_hi / dx)) * dx + dx / 2
    Y, Z = np.meshgrid(ys, zs, indexing="ij")
    yz = np.stack([Y.ravel(), Z.ravel()], axis=1)
    keep = (yz[:, 0] > u_lo) & (yz[:, 0] < u_hi) & (yz[:, 1] > v_lo) & (yz[:, 1] < v_hi)
    return yz[keep]


def extrude(yz, dx=DX):
    """Repeat section points along x (cell-centred, |x| < LENGTH / 2) into 3D positions."""
    xs = (np.arange(round(LENGTH / dx)) + 0.5) * dx - LENGTH / 2
    X = np.repeat(xs, len(yz))
    YZ = np.tile(yz, (len(xs), 1))
    return np.column_stack([X, YZ])


def write_run(folder, yz, bead, frames=1, dx=DX, plate=True, pos=None):
    """A run folder with particles.h5 holding `frames` identical frames of these beads (or
    of the 3D positions ``pos``, one bead)."""
    folder.mkdir(parents=True, exist_ok=True)
    if pos is None:
        pos = extrude(yz, dx)
        ids = np.tile(bead, round(LENGTH / dx))
    else:
        ids = np.zeros(len(pos), np.int32)
    config = {"spacing_m": dx, "section_point_m": [0.0, 0.0, 0.0],
              "section_direction": [1.0, 0.0, 0.0], "scene": "synthetic"}
    with h5py.File(folder / "particles.h5", "w") as h5:
        h5.attrs["config"] = json.dumps(config)
        h5.attrs["units"] = json.dumps({"position": "m"})
        if plate:
            lo, hi = pos[:, 1].min() - 10 * dx, pos[:, 1].max() + 10 * dx
            ys = np.arange(lo, hi, dx) + dx / 2
            xs = np.unique(pos[:, 0])
            X, Y, Z = np.meshgrid(xs, ys, -(np.arange(3) + 0.5) * dx, indexing="ij")
            h5["plate/position"] = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
        for i in range(frames):
            g = h5.create_group(f"frames/{i:06d}")
            g.attrs["time_s"] = 0.1 * i
            g.attrs["step"] = 10 * i
            g["position"] = pos
            g["velocity"] = np.zeros_like(pos)
            g["density"] = np.full(len(pos), 1240.0)
            g["pressure"] = np.zeros(len(pos))
            g["bead_id"] = ids.astype(np.int32)
            g["phase"] = np.zeros(len(pos), np.int32)
    return folder


def test_slicer_model_inverts_the_rounded_rectangle():
    W, H = 0.45, 0.2
    area = (W - H) * H + math.pi * H**2 / 4
    assert analysis.slicer_model(area, H) == pytest.approx(W)
    with pytest.raises(UserInputError):
        analysis.slicer_model(0.1, 0.0)


def test_the_sections_reference_outline_is_the_slicers_section(tmp_path):
    """The dashed outline drawn over a section encloses the bead's own area at height g and
    spans the slicer's width; a run with a plan gets it on its section picture."""
    area, g = 0.0814, 0.2
    width = analysis.slicer_model(area, g)
    ring = analysis.rounded_rectangle_outline(width, g, 10.0, 0.05, points=2000)
    u, v = ring[:, 0], ring[:, 1]
    enclosed = 0.5 * abs(np.dot(u[:-1], v[1:]) - np.dot(u[1:], v[:-1]))
    assert enclosed == pytest.approx(area, rel=1e-5)
    assert np.ptp(u) == pytest.approx(width) and (v.min(), v.max()) == pytest.approx((0.05, 0.25))
    assert analysis.layer_height_mm({"layer_z_mm": [0.2, 0.4], "selected_layers": "2"}) == pytest.approx(0.2)
    assert analysis.layer_height_mm({}) is None

    W, H = 0.48e-3, 0.2e-3
    yz = lattice_section(-W / 2, W / 2, 0.0, H)
    run = write_run(tmp_path, yz, np.zeros(len(yz)))
    (run / "plan.json").write_text(json.dumps({"layer_z_mm": [0.2], "selected_layers": "1"}))
    result = analysis.analyse_run(run)
    assert (run / result["sections"][0]["png"]).stat().st_size > 0


def test_single_rectangular_bead(tmp_path):
    W, H = 0.48e-3, 0.2e-3           # 12 x 5 particles
    yz = lattice_section(-W / 2, W / 2, 0.0, H)
    frame = analysis.load_frame(write_run(tmp_path, yz, np.zeros(len(yz))) / "particles.h5")
    sec = analysis.cross_section(frame, [0, 0, 0], [1, 0, 0], DX)
    (b,) = sec.beads
    pixel_mm = 1e3 * sec.pixel_m
    # extents within a pixel; area within 1 %: the smoothing rounds the two free corners
    assert b["width_mm"] == pytest.approx(0.48, abs=1.01 * pixel_mm)
    assert b["height_mm"] == pytest.approx(0.20, abs=1.01 * pixel_mm)
    assert b["area_mm2"] == pytest.approx(0.48 * 0.20, rel=0.01)
    assert b["centroid_mm"] == pytest.approx([0.0, 0.10], abs=0.5 * pixel_mm)
    assert sec.totals["void_fraction"] == 0.0
    (plate,) = sec.contacts   # only the plate: the bead's footprint is its width
    assert plate["kind"] == "plate"
    assert plate["neck_width_mm"] == pytest.approx(0.48, abs=2 * pixel_mm)


def test_column_tops_tell_a_flat_top_from_a_dome(tmp_path):
    """The flat-top test of issue 15 reads every column of the middle half: a rectangle's
    columns all stand at its height; a half-disc's rise from sqrt(3)/2 R to R over it."""
    W, H = 0.48e-3, 0.2e-3
    flat = lattice_section(-W / 2, W / 2, 0.0, H)
    R = 0.24e-3
    dome = lattice_section(-R, R, 0.0, R, DX / 2)
    dome = dome[np.hypot(dome[:, 0], dome[:, 1]) <= R]
    for name, yz, dx in (("flat", flat, DX), ("dome", dome, DX / 2)):
        run = write_run(tmp_path / name, yz, np.zeros(len(yz)), dx=dx)
        sec = analysis.cross_section(analysis.load_frame(run / "particles.h5"), [0, 0, 0],
                                     [1, 0, 0], dx)
        (b,) = sec.beads
        pixel_mm = 1e3 * sec.pixel_m
        if name == "flat":
            assert b["top_min_mm"] == pytest.approx(0.20, abs=1.01 * pixel_mm)
            assert b["top_max_mm"] == pytest.approx(0.20, abs=1.01 * pixel_mm)
        else:
            assert b["top_max_mm"] == pytest.approx(0.24, abs=1e3 * dx)
            assert b["top_min_mm"] == pytest.approx(0.24 * math.sqrt(3) / 2, abs=1e3 * dx)
        assert b["top_min_mm"] <= b["top_median_mm"] <= b["top_max_mm"]
        assert sec.totals["top_min_mm"] == b["top_min_mm"]


def test_neck_between_two_overlapping_round_beads(tmp_path):
    dx = DX / 2                       # ten particles per radius: the lattice disc is close to round
    R, d = 0.2e-3, 0.3e-3             # radius, centre distance: overlap 0.1 mm
    zc = 0.4e-3                       # clear of the plate
    yz = lattice_section(-d / 2 - R, d / 2 + R, zc - R, zc + R, dx)
    left = np.hypot(yz[:, 0] + d / 2, yz[:, 1] - zc) <= R
    right = np.hypot(yz[:, 0] - d / 2, yz[:, 1] - zc) <= R
    yz, bead = yz[left | right], (yz[:, 0] > 0)[left | right].astype(int)
    frame = analysis.load_frame(write_run(tmp_path, yz, bead, dx=dx) / "particles.h5")
    sec = analysis.cross_section(frame, [0, 0, 0], [1, 0, 0], dx)
    (neck,) = sec.contacts
    truth = 2e3 * math.sqrt(R**2 - (d / 2) ** 2)          # 0.2646 mm
    assert neck["kind"] == "side" and sorted(neck["beads"]) == [0, 1]
    # the lattice's own neck is 14 particles (0.28 mm): within one spacing of the circles'
    assert neck["neck_width_mm"] == pytest.approx(truth, abs=1e3 * dx)
    for b in sec.beads:
        assert b["height_mm"] == pytest.approx(0.4, abs=1e3 * dx / 2)
        assert b["width_mm"] == pytest.approx(0.35, abs=1e3 * dx / 2)
        area = math.pi * 0.2**2 - (0.2**2 * math.acos(0.75) - 0.15 * math.sqrt(0.2**2 - 0.15**2))
        assert b["area_mm2"] == pytest.approx(area, rel=0.03)
        assert b["particle_area_mm2"] == pytest.approx(b["area_mm2"], rel=0.03)


def test_void_fraction_of_a_block_with_a_hole(tmp_path):
    W, H = 0.4e-3, 0.2e-3             # 2 x 2 beads, 10 x 5 particles each
    hole = (-0.12e-3, 0.12e-3, 0.12e-3, 0.28e-3)   # 6 x 4 particles, across the junction
    yz = lattice_section(-W, W, 0.0, 2 * H)
    inside = ((yz[:, 0] > hole[0]) & (yz[:, 0] < hole[1]) & (yz[:, 1] > hole[2]) & (yz[:, 1] < hole[3]))
    yz = yz[~inside]
    bead = (yz[:, 0] > 0).astype(int) + 2 * (yz[:, 1] > H).astype(int)
    run = write_run(tmp_path / "run", yz, bead, frames=2)
    report = analysis.analyse_run(run)
    (sec,) = report["sections"]
    hole_area = 0.24 * 0.16
    truth = hole_area / (0.8 * 0.4)                                # 0.12
    assert sec["void_fraction"] == pytest.approx(truth, abs=0.01)
    assert sec["voids_count"] == 1
    assert sec["voids"][0]["area_mm2"] == pytest.approx(hole_area, rel=0.1)
    assert sec["beads_count"] == 4
    kinds = sorted(c["kind"] for c in sec["contacts"])
    assert kinds.count("side") == 2 and kinds.count("layer") == 2 and kinds.count("plate") == 2
    # the hole takes 0.08 mm off each side neck (0.2 high) and 0.12 off each layer neck (0.4 wide)
    for c in sec["contacts"]:
        expect = {"side": 0.12, "layer": 0.28, "plate": 0.4}[c["kind"]]
        assert c["neck_width_mm"] == pytest.approx(expect, abs=0.011)
    assert (run / "mesostructure.json").is_file()
    assert json.loads((run / "mesostructure.json").read_text())["frame"]["index"] == 1
    png = run / sec["png"]
    assert png.is_file() and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_cli_extra_positions_and_bad_inputs(tmp_path, capsys):
    from taichi_mex.app.analyse import main as analyse_main

    yz = lattice_section(-0.2e-3, 0.2e-3, 0.0, 0.2e-3)
    run = write_run(tmp_path / "run", yz, np.zeros(len(yz)), frames=2)
    assert analyse_main([str(run), "--frame", "0", "--at", "0.1"]) == 0
    assert "void 0.00 %" in capsys.readouterr().out
    report = json.loads((run / "mesostructure.json").read_text())
    assert [s["position"]["coordinate_mm"] for s in report["sections"]] == pytest.approx([0.0, 0.1])
    assert len(list((run / "sections").glob("section_*.png"))) == 2
    with pytest.raises(UserInputError, match="frame 5 does not exist"):
        analyse_main([str(run), "--frame", "5"])
    with pytest.raises(UserInputError, match="cuts no melt"):
        analyse_main([str(run), "--at", "3"])
    with pytest.raises(UserInputError, match="No run folder"):
        analyse_main([str(tmp_path / "missing")])
    with pytest.raises(UserInputError, match="No particles file"):
        analyse_main([str(tmp_path)])
    with pytest.raises(UserInputError):
        analyse_main([str(run), "--frame", "last"])
    with pytest.raises(UserInputError, match="horizontal"):
        analyse_main([str(run), "--direction", "0", "0"])
    with pytest.raises(UserInputError, match="horizontal"):
        analysis.cross_section(analysis.load_frame(run / "particles.h5"), [0, 0, 0], [0, 0, 1], DX)


def test_interface_chords_split_pieces_and_follow_staircases():
    # two vertical edges stacked (one piece) and, apart, three horizontal edges in a row
    straight = [(1, 2), (3, 2), (10, 1), (10, 3), (10, 5)]
    assert sorted(analysis._interface_chords(np.array(straight))) == pytest.approx([2.0, 3.0])
    # a staircase: vertical, horizontal, vertical, horizontal... joined at pixel corners
    stairs = [(1, 2), (2, 3), (3, 4), (4, 5), (5, 6), (6, 7)]
    assert analysis._interface_chords(np.array(stairs)) == pytest.approx([math.hypot(3, 3)])


@pytest.mark.parametrize("jitter", [0.15, 0.3])
def test_disordered_full_density_melt_reads_as_full(jitter):
    """A block of melt at full density but with particles jittered (Gaussian, `jitter`
    spacings) like a flowed bead: no voids and the area within 5 %. This is what lets the
    voids in a simulated bead's section be read as real gaps between particles."""
    rng = np.random.default_rng(7)
    yz = lattice_section(-10 * DX, 10 * DX, 0.0, 5 * DX)
    pos = extrude(yz)
    pos = pos + rng.normal(0.0, jitter * DX, pos.shape)
    pos[:, 2] = np.maximum(pos[:, 2], 0.3 * DX)
    frame = {"position": pos, "phase": np.zeros(len(pos), int), "bead_id": np.zeros(len(pos), int)}
    d = analysis.cross_section(frame, [0.0, 0.0, 2.5 * DX], [1.0, 0.0, 0.0], DX).to_dict()
    assert d["voids_count"] == 0 and d["void_fraction"] == 0.0
    assert d["mean_area_mm2"] == pytest.approx(20 * 5 * (DX * 1e3) ** 2, rel=0.05)


def test_the_middle_of_a_bead_is_read_over_nine_sections(tmp_path):
    """A bead 0.32 mm wide over one half of its length and 0.48 mm over the other: the
    middle's nine sections report both widths as their smallest and largest and a mean
    between them (what the summary's bead figures are); a uniform bead's mean is its one
    section's figure."""
    xs = (np.arange(40) + 0.5) * DX - 20 * DX
    narrow = lattice_section(-0.16e-3, 0.16e-3, 0.0, 0.2e-3)
    wide = lattice_section(-0.24e-3, 0.24e-3, 0.0, 0.2e-3)
    pos = np.concatenate([np.column_stack([np.full(len(yz), x), yz])
                          for x in xs for yz in [narrow if x < 0 else wide]])
    report = analysis.analyse_run(write_run(tmp_path / "step", None, None, pos=pos))
    mid = report["along_middle"]
    assert mid["sections"] == analysis.ALONG_SECTIONS == 9
    assert mid["coordinates_mm"][0] == pytest.approx(-0.39, abs=0.01)
    assert mid["coordinates_mm"][-1] == pytest.approx(0.39, abs=0.01)
    assert mid["width_min_mm"] == pytest.approx(0.32, abs=1e3 * DX / 2)
    assert mid["width_max_mm"] == pytest.approx(0.48, abs=1e3 * DX / 2)
    assert 0.36 < mid["mean_width_mm"] < 0.44
    assert mid["height_min_mm"] == pytest.approx(0.2, abs=1e3 * DX / 2)

    yz = lattice_section(-0.2e-3, 0.2e-3, 0.0, 0.2e-3)
    report = analysis.analyse_run(write_run(tmp_path / "even", yz, np.zeros(len(yz))))
    (sec,), mid = report["sections"], report["along_middle"]
    assert mid["mean_width_mm"] == pytest.approx(sec["mean_width_mm"])
    assert mid["width_min_mm"] == mid["width_max_mm"]
    assert "along_middle" not in analysis.analyse_run(tmp_path / "even", along=0)


def test_summary_and_sweep_read_the_same_section_figures():
    """The summary and a sweep's table take the middle's means where measured and the default
    section's necks and counts (one helper, post/analysis.py::headline_section)."""
    from taichi_mex.app.jobs import mesostructure_metrics
    from taichi_mex.post.analysis import headline_section

    default = {"mean_width_mm": 0.5, "mean_height_mm": 0.2, "mean_area_mm2": 0.09,
               "void_fraction": 0.1, "beads_count": 2, "mean_neck_side_mm": 0.15}
    middle = {"mean_width_mm": 0.46, "mean_height_mm": 0.19, "mean_area_mm2": 0.08,
              "void_fraction": 0.05, "width_min_mm": 0.44, "width_max_mm": 0.48, "sections": 9}
    both = {"sections": [default], "along_middle": middle}
    head = headline_section(both)
    assert head["mean_width_mm"] == 0.46 and head["beads_count"] == 2 and head["sections"] == 9
    assert headline_section({"sections": [default]})["mean_width_mm"] == 0.5
    m = mesostructure_metrics(both)
    assert m["bead_width_mm"] == 0.46 and m["void_fraction"] == 0.05
    assert m["beads_count"] == 2 and m["neck_side_mm"] == 0.15
