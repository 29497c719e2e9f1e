; paper_bead.gcode - the seed paper's single bead: nozzle one diameter (0.4 mm) above the plate.
; Shows: a 3 mm bead along +X at 60 mm/s with the bead cross-section equal to the nozzle bore
; (0.12566 mm^2), i.e. melt leaves the nozzle at the nozzle speed, as in the paper.
; Printer preset: prusa_mini (pyGCodeDecode bundled; 0.4 mm nozzle, 1.75 mm filament).
; Filament: PLA, 1.75 mm diameter, E in mm of filament (M83 relative).

G21 ; millimetres
G90 ; absolute XYZ
M83 ; relative E
G92 E0
;LAYER_CHANGE
;Z:0.4
G1 Z0.8 F720 ; lift for travel
G1 X10 Y10 F6000 ; travel to bead start
G1 Z0.4 F720
G1 F3600
G1 X13 Y10 E0.15673 ; layer 1 bead 1
G1 E-0.8 F2100 ; retract
G1 Z1.20 F720 ; lift
M107
