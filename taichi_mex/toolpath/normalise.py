"""Rewrite a slicer's G-code into the small, unambiguous dialect that pyGCodeDecode plans well.

pyGCodeDecode 1.5.1 plans motion like printer firmware, but its parser has pitfalls
(measured, see issue 2): it drops lowercase commands, treats ``G01`` as ``G0``, offsets
``G92 E<v>`` with the wrong sign for ``v != 0``, ignores ``G20`` and ``M221``, skips
``G2``/``G3`` arcs, and finds command names inside free text (``M117 G1``). Rather than
patch it, we hand it a canonical file with the same line numbers:

* ``G0``/``G1`` with absolute *physical* X/Y/Z (``G90``/``G91``/``G92`` resolved here) and
  *relative* E already multiplied by the ``M221`` flow factor;
* ``G4``, ``M203``, ``M204 P``, ``M205`` kept; every other command blanked (comments kept).

Arcs and inches are refused with an actionable message: converting them silently would
be a guess about the user's firmware.
"""

from __future__ import annotations

import re
from collections import Counter
from dataclasses import dataclass, field

from taichi_mex.errors import GCodeError

_AXES = ("X", "Y", "Z")
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)"
_WORDS_RE = re.compile(rf"(?:[A-Z](?:{_NUMBER})?)*")
_WORD_RE = re.compile(rf"([A-Z])({_NUMBER})?")
_LINE_NUMBER_RE = re.compile(r"^N\d+")
_CHECKSUM_RE = re.compile(r"\*\d+$")

#: commands we pass on, and the parameter letters we read from them; a wrong letter is an
#: error on motion commands and silently dropped on firmware-limit commands
_MOTION = {"G0", "G1", "G4", "G92"}
_STRICT = {
    "G0": set("XYZEF"),
    "G1": set("XYZEF"),
    "G4": set("PS"),
    "G92": set("XYZE"),
    "M203": set("XYZE"),
    "M204": set("PRST"),
    "M205": set("XYZEJS"),
    "M221": set("ST"),
}

_ARC_HINT = (
    "Re-slice with arc fitting switched off (PrusaSlicer/OrcaSlicer: Print Settings > "
    "Advanced > Arc fitting = Disabled; Cura: remove the ArcWelder plugin; or run the file "
    "through a de-arcing post-processor), then try again."
)

# PrusaSlicer/OrcaSlicer/SuperSlicer write ';LAYER_CHANGE', Cura ';LAYER:n',
# Simplify3D '; layer n, Z = ...'. BEFORE_/AFTER_LAYER_CHANGE are custom-G-code markers.
_LAYER_CUES = (
    re.compile(r"^LAYER_CHANGE$"),
    re.compile(r"^LAYER:\s*-?\d+$"),
    re.compile(r"^layer\s+\d+,\s*Z\s*=", re.IGNORECASE),
)


@dataclass
class NormalisedGCode:
    """The canonical text plus what was learnt while writing it."""

    text: str
    #: raw layer index per line (index 0 unused, lines are 1-based); 0 before the first cue
    line_layer: list[int]
    has_layer_cues: bool
    ignored_commands: Counter = field(default_factory=Counter)
    g92_resets: int = 0
    flow_factors: list[float] = field(default_factory=list)
    n_lines: int = 0


def _fmt(value: float) -> str:
    return format(value, ".10g")


def _parse_words(code: str, line_no: int, raw: str) -> list[tuple[str, str | None]]:
    compact = re.sub(r"\s+", "", code)
    if not _WORDS_RE.fullmatch(compact):
        raise GCodeError(
            f"Malformed G-code at line {line_no}: {raw.strip()!r}. Each word must be a "
            "letter followed by a number (for example 'G1 X10.5 E0.02'); fix or remove the "
            "line."
        )
    return [(m.group(1), m.group(2)) for m in _WORD_RE.finditer(compact)]


def _command_name(letter: str, number: str | None) -> str | None:
    if number is None:
        return None
    if "." in number:
        major, minor = number.split(".", 1)
        return f"{letter}{int(major)}.{minor}" if major.lstrip("+-").isdigit() else None
    return f"{letter}{int(number)}"


def normalise_gcode(
    text: str,
    initial_position_mm: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0),
) -> NormalisedGCode:
    """Return the canonical G-code for ``text`` (see module docstring).

    Raises :class:`GCodeError` for arcs, inch units, malformed motion lines and files that
    never move the nozzle.
    """
    raw_lines = text.splitlines()
    out: list[str] = []
    line_layer = [0]
    layer = 0
    has_cues = False

    physical = list(initial_position_mm[:3])
    offset = [0.0, 0.0, 0.0]
    e_logical = float(initial_position_mm[3])
    xyz_absolute = True
    e_absolute = True
    flow = 1.0
    result = NormalisedGCode(text="", line_layer=line_layer, has_layer_cues=False)
    arcs: list[int] = []
    inches: list[int] = []
    moves = 0

    for line_no, raw in enumerate(raw_lines, start=1):
        code, sep, comment = raw.partition(";")
        comment_text = comment.strip()
        if sep and any(cue.match(comment_text) for cue in _LAYER_CUES):
            layer += 1
            has_cues = True
        line_layer.append(layer)
        keep_comment = f";{comment}" if sep else ""

        code = _CHECKSUM_RE.sub("", code.strip().upper())
        code = _LINE_NUMBER_RE.sub("", code).strip()
        if not code:
            out.append(keep_comment)
            continue

        first = _WORD_RE.match(re.sub(r"\s+", "", code))
        name = _command_name(first.group(1), first.group(2)) if first else None
        if name in ("G2", "G3"):
            arcs.append(line_no)
            out.append(keep_comment)
            continue
        if name == "G20":
            inches.append(line_no)
            out.append(keep_comment)
            continue
        if name not in _STRICT and name not in ("G21", "G90", "G91", "M82", "M83"):
            result.ignored_commands[name or code.split()[0]] += 1
            out.append(keep_comment)
            continue

        words = _parse_words(code, line_no, raw)
        params: dict[str, float] = {}
        for letter, number in words[1:]:
            allowed = _STRICT.get(name, set())
            if letter in ("G", "M"):
                raise GCodeError(
                    f"Line {line_no} holds two commands ({raw.strip()!r}); taichi_mex expects "
                    "one G or M command per line. Split the line and try again."
                )
            if (letter not in allowed or number is None) and name not in _MOTION:
                continue
            if letter not in allowed or number is None:
                raise GCodeError(
                    f"Malformed {name} at line {line_no}: {raw.strip()!r}. {name} takes "
                    f"{', '.join(sorted(allowed)) or 'no parameters'}, each with a number."
                )
            params[letter] = float(number)

        if name == "G90":
            xyz_absolute = True
            line = ""
        elif name == "G91":
            xyz_absolute = False
            line = ""
        elif name == "M82":
            e_absolute = True
            line = ""
        elif name == "M83":
            e_absolute = False
            line = ""
        elif name == "G21":
            line = ""
        elif name == "M221":
            if "S" in params:
                if params["S"] <= 0:
                    raise GCodeError(
                        f"M221 at line {line_no} sets a flow of {params['S']:g} %; a flow "
                        "factor must be positive."
                    )
                flow = params["S"] / 100.0
                result.flow_factors.append(flow)
            line = ""
        elif name == "G92":
            result.g92_resets += 1
            if not params:
                params = {"X": 0.0, "Y": 0.0, "Z": 0.0, "E": 0.0}
            for k, axis in enumerate(_AXES):
                if axis in params:
                    offset[k] = physical[k] - params[axis]
            if "E" in params:
                e_logical = params["E"]
            line = ""
        elif name in ("G0", "G1"):
            parts = ["G1"]
            for k, axis in enumerate(_AXES):
                if axis in params:
                    logical = params[axis] if xyz_absolute else physical[k] - offset[k] + params[axis]
                    physical[k] = logical + offset[k]
                    parts.append(f"{axis}{_fmt(physical[k])}")
                    moves += 1
            if "E" in params:
                delta = params["E"] - e_logical if e_absolute else params["E"]
                e_logical = e_logical + delta
                parts.append(f"E{_fmt(delta * flow)}")
            if "F" in params:
                if params["F"] <= 0:
                    raise GCodeError(
                        f"Feed rate F{params['F']:g} at line {line_no} is not positive; "
                        "fix the line."
                    )
                parts.append(f"F{_fmt(params['F'])}")
            line = " ".join(parts) if len(parts) > 1 else ""
        elif name == "M204":
            accel = params.get("P", params.get("S"))
            line = f"M204 P{_fmt(accel)}" if accel is not None and accel > 0 else ""
        else:  # G4, M203, M205: pyGCodeDecode reads these as written
            line = " ".join([name] + [f"{k}{_fmt(v)}" for k, v in params.items()])
        out.append(f"{line} {keep_comment}".strip() if line else keep_comment)

    if arcs:
        shown = ", ".join(str(n) for n in arcs[:5]) + (" ..." if len(arcs) > 5 else "")
        raise GCodeError(
            f"The G-code contains {len(arcs)} arc move(s) (G2/G3, first at line(s) {shown}). "
            f"pyGCodeDecode cannot plan arcs and would lose their end points. {_ARC_HINT}"
        )
    if inches:
        raise GCodeError(
            f"The G-code switches to inch units (G20 at line {inches[0]}). taichi_mex reads "
            "G-code in millimetres only; export the file in mm (G21) and try again."
        )
    if moves == 0:
        raise GCodeError(
            "The G-code never moves the nozzle (no G0/G1 with X, Y or Z). Check that this is "
            "the sliced file and not a start/end script."
        )

    result.text = "\n".join(out) + "\n"
    result.line_layer = line_layer
    result.has_layer_cues = has_cues
    result.n_lines = len(raw_lines)
    return result
