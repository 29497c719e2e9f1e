"""Small G-code writers and rewriters for parameter studies.

* :func:`write_pattern` writes a single bead or a block of parallel beads in the dialect of
  our bundled files (``gcode/*.gcode``): millimetres, absolute XYZ, relative E (``M83``),
  PrusaSlicer's ``;LAYER_CHANGE`` / ``;Z:`` cues, every bead along +X with a lifted travel
  back. Layer height, line width and speed are free, so a study can vary them.
* :func:`scale_words` rewrites an existing file with every feed rate (``F``) or every
  extrusion (``E``) multiplied by a factor, leaving everything else byte for byte.

The extruded amount per mm of bead is the slicer's: a rounded rectangle of width W and
height H, A = (W - H) H + pi H^2 / 4 (PrusaSlicer's Flow model), divided by the filament
cross-section unless the printer counts E in mm^3. Adjacent beads sit
W - H (1 - pi/4) apart, so neighbouring rounded rectangles overlap by the slicer's amount.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from taichi_mex.errors import UserInputError

PATTERNS = ("bead", "block")

#: commands whose argument is free text: never rewritten
_TEXT_COMMANDS = {"M23", "M28", "M30", "M32", "M117", "M118"}
#: commands that move (and so carry F and E words)
_MOVE_COMMANDS = {"G0", "G1", "G2", "G3", "G92"}
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)"
_COMMAND_RE = re.compile(r"^\s*(?:N\d+\s*)?([GMT])\s*0*(\d+)", re.IGNORECASE)
_CHECKSUM_RE = re.compile(r"\*\s*\d+\s*$")


def bead_area_mm2(width_mm: float, height_mm: float) -> float:
    """Slicer cross-section of one bead: (W - H) H + pi H^2 / 4."""
    return (width_mm - height_mm) * height_mm + math.pi * height_mm**2 / 4.0


def line_spacing_mm(width_mm: float, height_mm: float) -> float:
    """Centre distance of adjacent beads in PrusaSlicer: W - H (1 - pi/4)."""
    return width_mm - height_mm * (1.0 - math.pi / 4.0)


def _fmt(value: float, digits: int = 5) -> str:
    text = f"{value:.{digits}f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def check_pattern(*, pattern: str = "bead", layer_height_mm: float = 0.2,
                  line_width_mm: float = 0.45, speed_mm_s: float = 60.0,
                  bead_length_mm: float = 3.0, beads: int = 1, layers: int = 1,
                  printer: str = "prusa_mini", travel_speed_mm_s: float = 100.0) -> None:
    """Refuse (UserInputError) what :func:`write_pattern` cannot write sensibly."""
    if pattern not in PATTERNS:
        raise UserInputError(f"Unknown pattern '{pattern}'; choose {' or '.join(PATTERNS)}.")
    if pattern == "bead" and (beads != 1 or layers != 1):
        raise UserInputError("pattern 'bead' is one bead on one layer; use pattern 'block' for "
                             f"{beads} bead(s) x {layers} layer(s).")
    for name, value in (("layer_height_mm", layer_height_mm), ("line_width_mm", line_width_mm),
                        ("speed_mm_s", speed_mm_s), ("bead_length_mm", bead_length_mm),
                        ("travel_speed_mm_s", travel_speed_mm_s)):
        if isinstance(value, bool) or not (isinstance(value, (int, float)) and math.isfinite(value)
                                           and value > 0):
            raise UserInputError(f"{name} must be a positive number, got {value!r}.")
    if line_width_mm < layer_height_mm:
        raise UserInputError(
            f"line_width_mm {line_width_mm} is below layer_height_mm {layer_height_mm}: a slicer "
            "bead (rounded rectangle) is at least as wide as it is high. Widen the line or lower "
            "the layer.")
    for name, value in (("beads", beads), ("layers", layers)):
        if isinstance(value, bool) or not (isinstance(value, int) and value >= 1):
            raise UserInputError(f"{name} must be a whole number >= 1, got {value!r}.")
    from taichi_mex.toolpath.trajectory import load_printer

    load_printer(printer)


def write_pattern(path, *, pattern: str = "bead", layer_height_mm: float = 0.2,
                  line_width_mm: float = 0.45, speed_mm_s: float = 60.0,
                  bead_length_mm: float = 3.0, beads: int = 1, layers: int = 1,
                  printer: str = "prusa_mini", start_xy_mm: tuple[float, float] = (10.0, 10.0),
                  travel_speed_mm_s: float = 100.0, lift_mm: float = 0.4) -> Path:
    """Write a bead (``pattern='bead'``: one bead, one layer) or a block (``'block'``:
    ``layers`` x ``beads`` parallel beads along +X) and return the path."""
    from taichi_mex.toolpath.trajectory import load_printer

    check_pattern(pattern=pattern, layer_height_mm=layer_height_mm, line_width_mm=line_width_mm,
                  speed_mm_s=speed_mm_s, bead_length_mm=bead_length_mm, beads=beads,
                  layers=layers, printer=printer, travel_speed_mm_s=travel_speed_mm_s)
    preset = load_printer(printer)
    area = bead_area_mm2(line_width_mm, layer_height_mm)
    e_per_mm = area if preset.volumetric_extrusion else area / preset.filament_area_mm2
    e_bead = e_per_mm * bead_length_mm
    pitch = line_spacing_mm(line_width_mm, layer_height_mm)
    x0, y0 = start_xy_mm
    x1 = x0 + bead_length_mm
    travel_f = _fmt(60.0 * travel_speed_mm_s, 1)
    print_f = _fmt(60.0 * speed_mm_s, 3)
    what = "one bead" if pattern == "bead" else f"{layers} layer(s) x {beads} parallel bead(s)"
    lines = [
        f"; {Path(path).name} - written by taichi_mex.toolpath.generate: {what}.",
        f"; Beads of {_fmt(bead_length_mm)} mm along +X at {_fmt(speed_mm_s, 3)} mm/s, "
        f"{_fmt(layer_height_mm)} mm layer height, {_fmt(line_width_mm)} mm extrusion width",
        f"; (slicer rounded-rectangle area {_fmt(area)} mm^2 -> {_fmt(e_per_mm)} "
        f"{'mm^3' if preset.volumetric_extrusion else 'mm of filament'} per mm), "
        f"line spacing {_fmt(pitch)} mm.",
        f"; Printer preset: {preset.name} ({preset.nozzle_diameter_mm} mm nozzle, "
        f"{preset.filament_diameter_mm} mm filament).",
        "",
        "G21 ; millimetres",
        "G90 ; absolute XYZ",
        "M83 ; relative E",
        "G92 E0",
    ]
    for layer in range(1, layers + 1):
        z = layer * layer_height_mm
        lines += [";LAYER_CHANGE", f";Z:{_fmt(z)}"]
        for bead in range(1, beads + 1):
            y = y0 + (bead - 1) * pitch
            lines += [
                f"G1 Z{_fmt(z + lift_mm)} F720 ; lift for travel",
                f"G1 X{_fmt(x0)} Y{_fmt(y)} F{travel_f} ; travel to bead start",
                f"G1 Z{_fmt(z)} F720",
                f"G1 F{print_f}",
                f"G1 X{_fmt(x1)} Y{_fmt(y)} E{_fmt(e_bead)} ; layer {layer} bead {bead}",
            ]
    z_top = layers * layer_height_mm
    lines += ["G1 E-0.8 F2100 ; retract", f"G1 Z{_fmt(z_top + 2 * lift_mm)} F720 ; lift", "M107", ""]
    path = Path(path)
    path.write_text("\n".join(lines))
    return path


def _checksum(text: str) -> int:
    value = 0
    for ch in text.encode("ascii", "replace"):
        value ^= ch
    return value


def scale_words(text: str, letter: str, factor: float) -> tuple[str, int]:
    """Multiply every ``letter`` word (``'F'`` or ``'E'``) of the move commands by ``factor``.

    Comments, free-text commands (``M117``...) and all other words stay as they are; a line
    with a checksum gets a new one. Returns the new text and the number of words changed.
    Scaling every ``E`` (``G92 E`` included) keeps relative and absolute extrusion consistent.
    """
    letter = letter.upper()
    if letter not in ("F", "E"):
        raise ValueError("scale_words rewrites F or E words")
    if not (isinstance(factor, (int, float)) and math.isfinite(factor) and factor > 0):
        raise UserInputError(f"A {letter} factor must be a positive number, got {factor!r}.")
    word = re.compile(rf"(?<![A-Za-z])([{letter}{letter.lower()}])(\s*)({_NUMBER})")
    changed = 0
    out = []
    for line in text.splitlines(keepends=True):
        body = line.rstrip("\r\n")
        ending = line[len(body):]
        code, sep, comment = body.partition(";")
        head, paren, tail = code.partition("(")  # (...) comments: leave the rest alone
        m = _COMMAND_RE.match(head)
        name = f"{m.group(1).upper()}{int(m.group(2))}" if m else None
        if name is None or name in _TEXT_COMMANDS or name not in _MOVE_COMMANDS:
            out.append(line)
            continue
        checksum = _CHECKSUM_RE.search(head)
        core = head[: checksum.start()] if checksum else head

        def _scale(match):
            nonlocal changed
            changed += 1
            value = float(match.group(3)) * factor
            return f"{match.group(1)}{match.group(2)}{_fmt(value, 6)}"

        new_core = word.sub(_scale, core)
        if new_core == core:
            out.append(line)
            continue
        if checksum:
            # the star goes right after the code; reprap firmware checks the XOR of the bytes before it
            stripped = new_core.rstrip()
            new_core = f"{stripped}*{_checksum(stripped)}" + core[len(core.rstrip()):]
        out.append(new_core + paren + tail + sep + comment + ending)
    return "".join(out), changed


def write_scaled(source, target, feed_rate_factor: float = 1.0, flow_factor: float = 1.0) -> Path:
    """Copy ``source`` to ``target`` with feed rates and/or extrusion scaled; refuse a file
    that has nothing to scale (the factor would silently do nothing)."""
    text = Path(source).read_text(errors="replace")
    header = []
    if feed_rate_factor != 1.0:
        text, n = scale_words(text, "F", feed_rate_factor)
        if n == 0:
            raise UserInputError(f"feed_rate_factor: {source} has no F words on its moves; nothing "
                                 "to scale.")
        header.append(f"every F x {feed_rate_factor:g} ({n} words)")
    if flow_factor != 1.0:
        text, n = scale_words(text, "E", flow_factor)
        if n == 0:
            raise UserInputError(f"flow_factor: {source} has no E words on its moves; nothing to "
                                 "scale.")
        header.append(f"every E x {flow_factor:g} ({n} words)")
    note = f"; taichi_mex sweep: copy of {Path(source).name} with {', '.join(header)}\n" if header else ""
    target = Path(target)
    target.write_text(note + text)
    return target
