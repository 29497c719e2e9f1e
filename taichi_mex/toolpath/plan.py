"""What a print run will simulate, worked out before any particle exists (``--dry-run``)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from taichi_mex.toolpath.trajectory import Selection, Trajectory, load_trajectory


@dataclass
class PrintPlan:
    trajectory: Trajectory
    selection: Selection

    def as_dict(self) -> dict:
        traj = self.trajectory
        norm = traj.gcode
        out = {
            "gcode": traj.source,
            "printer": traj.printer.name,
            "nozzle_diameter_mm": traj.printer.nozzle_diameter_mm,
            "filament_diameter_mm": traj.printer.filament_diameter_mm,
            "print_time_s": traj.print_time_s,
            "extruding_time_s": traj.extruding_time_s,
            "extruded_volume_mm3": traj.extruded_volume_mm3,
            "n_layers": traj.n_layers,
            "planned_through_layer": traj.planned_through_layer,
            "layers_in_file": traj.layers_in_file or traj.n_layers,
            "layer_z_mm": traj.layer_z_mm[1:].tolist(),
            "n_segments": traj.n_segments,
            "n_extruding_intervals": len(traj.extruding_intervals()),
            "layer_detection": "slicer comments" if norm.has_layer_cues else "Z of extruding moves",
            "ignored_commands": dict(norm.ignored_commands.most_common()),
            "g92_resets": norm.g92_resets,
            "flow_factors_applied": sorted(set(norm.flow_factors)),
        }
        out.update(self.selection.report())
        return out

    def describe(self) -> str:
        d = self.as_dict()
        t0, t1 = d["selected_time_window_s"]
        share = d["selected_extruded_volume_mm3"] / d["extruded_volume_mm3"]
        cut = d["planned_through_layer"]
        planned = (f"planned through layer {cut} of {d['layers_in_file']} (nothing after the "
                   "selection is needed): " if cut else "")
        lines = [
            f"G-code   {d['gcode']}  (printer {d['printer']}, nozzle {d['nozzle_diameter_mm']} mm, "
            f"filament {d['filament_diameter_mm']} mm)",
            f"print    {planned}{d['print_time_s']:.3f} s in {d['n_segments']} planned segments, "
            + ("" if cut else f"{d['n_layers']} layer(s) ")
            + f"({d['layer_detection']}), extruding {d['extruding_time_s']:.3f} s, "
            f"{d['extruded_volume_mm3']:.4f} mm^3 of bead",
            f"selected layers {d['selected_layers']}, time {t0:.4f}-{t1:.4f} s"
            + (f", region {d['selected_region_mm']} mm" if d["selected_region_mm"] else "")
            + f": {d['selected_extruded_volume_mm3']:.4g} mm^3 ({_percent(share)} of the "
            + ("planned " if cut else "") + "bead volume)",
        ]
        if d["ignored_commands"]:
            shown = ", ".join(f"{k} x{v}" for k, v in list(d["ignored_commands"].items())[:6])
            lines.append(f"ignored  commands that do not move the nozzle: {shown}")
        return "\n".join(lines)

    def write(self, out_dir: Path) -> Path:
        out_dir.mkdir(parents=True, exist_ok=True)
        path = out_dir / "plan.json"
        path.write_text(json.dumps(self.as_dict(), indent=2))
        return path


def make_plan(gcode, printer="prusa_mini", layers=None, until_s=None, region_mm=None,
              from_s: float = 0.0, plan_whole_file: bool = True) -> PrintPlan:
    """Plan the G-code and apply the selection (layers, time window, XY region).

    With ``plan_whole_file=False`` planning stops after the last selected layer, which
    saves minutes on large files; the plan's totals then cover the planned part only.
    """
    last = max(layers) if layers and not plan_whole_file else None
    traj = load_trajectory(gcode, printer, last_layer=last)
    window = None if until_s is None and from_s == 0.0 else (from_s, until_s if until_s is not None else traj.print_time_s)
    return PrintPlan(traj, traj.select(layers=layers, time_window_s=window, region_mm=region_mm))


def _percent(share: float) -> str:
    """A share as a percentage with the digits it needs (a part window is < 0.1 %)."""
    value = 100.0 * share
    return f"{value:.1f} %" if value >= 1 or value == 0 else f"{value:.2g} %"
