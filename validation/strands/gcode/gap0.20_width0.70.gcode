; gap0.20_width0.70.gcode - written by taichi_mex.toolpath.generate: one bead.
; Beads of 6 mm along +X at 60 mm/s, 0.2 mm layer height, 0.7 mm extrusion width
; (slicer rounded-rectangle area 0.13142 mm^2 -> 0.05464 mm of filament per mm), line spacing 0.65708 mm.
; Printer preset: prusa_mini (0.4 mm nozzle, 1.75 mm filament).

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
G1 X16 Y10 E0.32782 ; layer 1 bead 1
G1 E-0.8 F2100 ; retract
G1 Z1 F720 ; lift
M107
