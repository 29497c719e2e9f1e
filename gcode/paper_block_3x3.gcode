; paper_block_3x3.gcode - the seed paper's 3 layers x 3 parallel short beads, nozzle one diameter up.
; Shows: 3 mm beads at 60 mm/s, bead area = nozzle bore area (0.12566 mm^2), 0.4 mm line spacing,
; 0.4 mm layer height (layer k at Z = 0.4 k mm): the geometry of the paper's Figures 5-7.
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
G1 Z0.8 F720 ; lift for travel
G1 X10 Y10.4 F6000 ; travel to bead start
G1 Z0.4 F720
G1 F3600
G1 X13 Y10.4 E0.15673 ; layer 1 bead 2
G1 Z0.8 F720 ; lift for travel
G1 X10 Y10.8 F6000 ; travel to bead start
G1 Z0.4 F720
G1 F3600
G1 X13 Y10.8 E0.15673 ; layer 1 bead 3
;LAYER_CHANGE
;Z:0.8
G1 Z1.2 F720 ; lift for travel
G1 X10 Y10 F6000 ; travel to bead start
G1 Z0.8 F720
G1 F3600
G1 X13 Y10 E0.15673 ; layer 2 bead 1
G1 Z1.2 F720 ; lift for travel
G1 X10 Y10.4 F6000 ; travel to bead start
G1 Z0.8 F720
G1 F3600
G1 X13 Y10.4 E0.15673 ; layer 2 bead 2
G1 Z1.2 F720 ; lift for travel
G1 X10 Y10.8 F6000 ; travel to bead start
G1 Z0.8 F720
G1 F3600
G1 X13 Y10.8 E0.15673 ; layer 2 bead 3
;LAYER_CHANGE
;Z:1.2
G1 Z1.6 F720 ; lift for travel
G1 X10 Y10 F6000 ; travel to bead start
G1 Z1.2 F720
G1 F3600
G1 X13 Y10 E0.15673 ; layer 3 bead 1
G1 Z1.6 F720 ; lift for travel
G1 X10 Y10.4 F6000 ; travel to bead start
G1 Z1.2 F720
G1 F3600
G1 X13 Y10.4 E0.15673 ; layer 3 bead 2
G1 Z1.6 F720 ; lift for travel
G1 X10 Y10.8 F6000 ; travel to bead start
G1 Z1.2 F720
G1 F3600
G1 X13 Y10.8 E0.15673 ; layer 3 bead 3
G1 E-0.8 F2100 ; retract
G1 Z1.80 F720 ; lift
M107
