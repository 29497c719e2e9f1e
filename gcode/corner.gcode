; corner.gcode - a bead with a sharp 90 degree corner.
; Shows: 5 mm along +X then 5 mm along +Y at a commanded 60 mm/s, 0.2 mm layer, 0.45 mm width.
; The firmware (prusa_mini: jerk 8 mm/s, 1250 mm/s^2) slows to the jerk speed at the corner, so the
; flow rate (mm^3/s) dips there while the filament per mm of path stays as commanded: the nozzle
; dwells longer per mm at the corner and the melt has more time to spread and cool there.
; Printer preset: prusa_mini (pyGCodeDecode bundled; 0.4 mm nozzle, 1.75 mm filament).
; Filament: PLA, 1.75 mm diameter, E in mm of filament (M83 relative).

G21 ; millimetres
G90 ; absolute XYZ
M83 ; relative E
G92 E0
;LAYER_CHANGE
;Z:0.2
G1 Z0.6 F720
G1 X10 Y10 F6000
G1 Z0.2 F720
G1 F3600
G1 X15 Y10 E0.16924 ; first leg
G1 X15 Y15 E0.16924 ; second leg after the corner
G1 E-0.8 F2100 ; retract
G1 Z1.00 F720 ; lift
M107
