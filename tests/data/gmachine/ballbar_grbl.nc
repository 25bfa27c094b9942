; J-DBB ballbar test, hand-made for the simulator's tests: grbl
; table ball at X150 Y100 Z-50; R 90 mm in XY at H 0; F1000; start angle 0
G21 G90 G94 G17
G0 X238 Y100 Z-50
M0 ; mount the instrument here, then cycle start
G4 P1.0
G1 X240 F1000 ; feed-in
G3 X150 Y190 I-90 J0 ; lead-in
G3 X150 Y10 I0 J-90
G3 X150 Y190 I0 J90
G3 X60 Y100 I0 J-90 ; overshoot
G4 P1.0 ; reversal
G2 X150 Y190 I90 J0
G2 X150 Y10 I0 J-90
G2 X150 Y190 I0 J90
G2 X240 Y100 I0 J-90
G1 X238 ; feed-out
G4 P1.0
M30
