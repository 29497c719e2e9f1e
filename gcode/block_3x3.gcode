; block_3x3.gcode - the seed paper's block: 3 layers x 3 parallel 3 mm beads, at real-printer gaps.
; Shows: beads at 60 mm/s, 0.2 mm layer height, 0.45 mm width, 0.40708 mm line spacing
; (PrusaSlicer spacing = width - height*(1 - pi/4)), every bead along +X; layer k sits at Z = 0.2 k mm.
; Printer preset: prusa_mini (pyGCodeDecode bundled; 0.4 mm nozzle, 1.75 mm filament).
; Filament: PLA, 1.75 mm diameter, E in mm of filament (M83 relative).

G21 ; millimetres
G90 ; absolute XYZ
M83 ; relative E
G92 E0
;LAYER_CHANGE
;Z:0.2
G1 Z0.6 F720 ; lift for travel
G1 X10 Y10 F6000 ; travel to bead start
G1 Z0.2 F720
G1 F3600
G1 X13 Y10 E0.10155 ; layer 1 bead 1
G1 Z0.6 F720 ; lift for travel
G1 X10 Y10.40708 F6000 ; travel to bead start
G1 Z0.2 F720
G1 F3600
G1 X13 Y10.40708 E0.10155 ; layer 1 bead 2
G1 Z0.6 F720 ; lift for travel
G1 X10 Y10.81416 F6000 ; travel to bead start
G1 Z0.2 F720
G1 F3600
G1 X13 Y10.81416 E0.10155 ; layer 1 bead 3
;LAYER_CHANGE
;Z:0.4
G1 Z0.8 F720 ; lift for travel
G1 X10 Y10 F6000 ; travel to bead start
G1 Z0.4 F720
G1 F3600
G1 X13 Y10 E0.10155 ; layer 2 bead 1
G1 Z0.8 F720 ; lift for travel
G1 X10 Y10.40708 F6000 ; travel to bead start
G1 Z0.4 F720
G1 F3600
G1 X13 Y10.40708 E0.10155 ; layer 2 bead 2
G1 Z0.8 F720 ; lift for travel
G1 X10 Y10.81416 F6000 ; travel to bead start
G1 Z0.4 F720
G1 F3600
G1 X13 Y10.81416 E0.10155 ; layer 2 bead 3
;LAYER_CHANGE
;Z:0.6
G1 Z1 F720 ; lift for travel
G1 X10 Y10 F6000 ; travel to bead start
G1 Z0.6 F720
G1 F3600
G1 X13 Y10 E0.10155 ; layer 3 bead 1
G1 Z1 F720 ; lift for travel
G1 X10 Y10.40708 F6000 ; travel to bead start
G1 Z0.6 F720
G1 F3600
G1 X13 Y10.40708 E0.10155 ; layer 3 bead 2
G1 Z1 F720 ; lift for travel
G1 X10 Y10.81416 F6000 ; travel to bead start
G1 Z0.6 F720
G1 F3600
G1 X13 Y10.81416 E0.10155 ; layer 3 bead 3
G1 E-0.8 F2100 ; retract
G1 Z1.40 F720 ; lift
M107
