"""``python -m taichi_mex analyse DIR``: the mesostructure of a saved run."""

from __future__ import annotations

from pathlib import Path

from taichi_mex.app.parsing import Parser
from taichi_mex.post.analysis import ALONG_SECTIONS, _mm, analyse_run


def main(argv: list[str]) -> int:
    """``python -m taichi_mex analyse DIR [--frame N] [--at X_MM ...]``."""
    p = Parser(prog="python -m taichi_mex analyse",
                description="Cross-sections of a saved frame: bead width, height, area and "
                "centroid, neck widths between beads and layers, void fraction. Writes "
                "DIR/mesostructure.json and DIR/sections/section_NN.png.")
    p.add_argument("dir", type=Path, help="the --out folder of a run (holds particles.h5)")
    p.add_argument("--frame", type=int, default=-1, help="frame index (default -1: the last)")
    p.add_argument("--at", type=float, nargs="+", metavar="X_MM", default=None,
                   help="extra sections at these G-code coordinates (mm) along the extrusion "
                   "direction's dominant axis (x for beads along x)")
    p.add_argument("--direction", type=float, nargs=2, metavar=("DX", "DY"), default=None,
                   help="extrusion direction, the sections' normal (default: the run's, "
                   "e.g. 1 0 for beads along x)")
    p.add_argument("--along", type=int, default=ALONG_SECTIONS, metavar="N",
                   help="sections over the middle half of the melt's length whose mean, "
                   f"smallest and largest figures are reported (default {ALONG_SECTIONS}; 0: none)")
    args = p.parse_args(argv)
    if args.along < 0:
        p.error(f"--along takes a count of sections, 0 or more, not {args.along}")
    direction = None if args.direction is None else [*args.direction, 0.0]
    report = analyse_run(args.dir, frame=args.frame, positions=args.at, direction=direction,
                         along=args.along)
    f = report["frame"]
    print(f"frame {f['index']} of {f['count']} (t = {f['time_s']:.4g} s)")
    for sec in report["sections"]:
        pos = sec["position"]
        print(f"{pos['axis']} = {pos['coordinate_mm']:.3f} mm: {sec['beads_count']} bead(s), "
              f"mean W {_mm(sec['mean_width_mm'])}, H {_mm(sec['mean_height_mm'])}, necks side "
              f"{_mm(sec['mean_neck_side_mm'])}, layer {_mm(sec['mean_neck_layer_mm'])}, "
              f"void {100 * sec['void_fraction']:.2f} % -> {sec['png']}")
    mid = report.get("along_middle")
    if mid:
        c = mid["coordinates_mm"]
        print(f"over the middle ({mid['sections']} sections, {mid['axis']} = {c[0]:.3f}-{c[-1]:.3f} "
              f"mm): W {_mm(mid['mean_width_mm'])} ({_mm(mid['width_min_mm'])}-"
              f"{_mm(mid['width_max_mm'])}), H {_mm(mid['mean_height_mm'])} "
              f"({_mm(mid['height_min_mm'])}-{_mm(mid['height_max_mm'])}), void "
              f"{100 * mid['void_fraction']:.2f} %")
    print(f"results in {args.dir / 'mesostructure.json'}")
    return 0
