; single_bead.gcode - one straight bead, the smallest printing scene.
; Shows: a 5 mm bead along +X at 60 mm/s, 0.2 mm layer height, 0.45 mm extrusion width
; (slicer rounded-rectangle area 0.08142 mm^2 -> 0.033849 mm of filament per mm).
; Printer preset: prusa_mini (pyGCodeDecode bundled; 0.4 mm nozzle, 1.75 mm filament).
; Filament: PLA, 1.75 mm diameter, E in mm of filament (M83 relative).
; The firmware accelerates from the junction speed to 60 mm/s and back (prusa_mini: 1250 mm/s^2),
; so the flow rate ramps with the nozzle speed at both ends.

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
G1 X15 Y10 E0.16924 ; layer 1 bead 1
G1 E-0.8 F2100 ; retract
G1 Z1.00 F720 ; lift
M107
