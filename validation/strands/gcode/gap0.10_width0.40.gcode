; gap0.10_width0.40.gcode - written by taichi_mex.toolpath.generate: one bead.
; Beads of 6 mm along +X at 60 mm/s, 0.1 mm layer height, 0.4 mm extrusion width
; (slicer rounded-rectangle area 0.03785 mm^2 -> 0.01574 mm of filament per mm), line spacing 0.37854 mm.
; Printer preset: prusa_mini (0.4 mm nozzle, 1.75 mm filament).

G21 ; millimetres
G90 ; absolute XYZ
M83 ; relative E
G92 E0
;LAYER_CHANGE
;Z:0.1
G1 Z0.5 F720 ; lift for travel
G1 X10 Y10 F6000 ; travel to bead start
G1 Z0.1 F720
G1 F3600
G1 X16 Y10 E0.09443 ; layer 1 bead 1
G1 E-0.8 F2100 ; retract
G1 Z0.9 F720 ; lift
M107
