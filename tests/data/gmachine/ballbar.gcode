; J-DBB ballbar test, hand-made for the simulator's tests: Marlin
; table ball at X150 Y100 Z-50; R 90 mm in XY at H 20 (Z-30): D = sqrt(90^2 + 20^2); F1000
G21
G90
G94
G17
G0 X238 Y100 Z-30
M0 ; mount the instrument here, then cycle start
G4 S1
G1 X240 F1000
G3 X150 Y190 I-90 J0
G3 X150 Y10 I0 J-90
G3 X150 Y190 I0 J90
G3 X60 Y100 I0 J-90
G4 P1000
G2 X150 Y190 I90 J0
G2 X150 Y10 I0 J-90
G2 X150 Y190 I0 J90
G2 X240 Y100 I0 J-90
G1 X238
G4 P1000
