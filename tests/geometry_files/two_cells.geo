// tests/geometry_files/small.geo with a second cell (1 and 2 ranks agree on it: tests/test_devices.py)
lc = 0.1; lcc = 0.015;
Point(1) = {0, 0, 0, lc}; Point(2) = {2, 0, 0, lc}; Point(3) = {2, 0.3, 0, lc}; Point(4) = {0, 0.3, 0, lc};
Point(5) = {2, -0.6, 0, lc}; Point(6) = {0, -0.6, 0, lc};
Line(1) = {1, 2};   // fluid-gel interface
Line(2) = {2, 3};   // outlet
Line(3) = {3, 4};   // wall
Line(4) = {4, 1};   // inlet
Line(5) = {2, 5}; Line(6) = {5, 6}; Line(7) = {6, 1};   // held gel walls
CX = 1.0; CY = -0.3; CR = 0.05;   // CELL
Point(10) = {CX, CY, 0, lcc}; Point(11) = {CX + CR, CY, 0, lcc}; Point(12) = {CX - CR, CY, 0, lcc};
Circle(10) = {11, 10, 12}; Circle(11) = {12, 10, 11};
Point(20) = {1.4, -0.2, 0, lcc}; Point(21) = {1.44, -0.2, 0, lcc}; Point(22) = {1.36, -0.2, 0, lcc};
Circle(20) = {21, 20, 22}; Circle(21) = {22, 20, 21};
Curve Loop(4) = {20, 21}; Plane Surface(4) = {4};
Curve Loop(1) = {1, 2, 3, 4}; Plane Surface(1) = {1};
Curve Loop(3) = {10, 11};
Curve Loop(2) = {5, 6, 7, 1}; Plane Surface(2) = {2, 3, 4};   // GEL
Plane Surface(3) = {3};
Physical Surface("fluid") = {1};
Physical Surface("gel") = {2};
Physical Surface("cell_1") = {3};
Physical Surface("cell_2") = {4};
Physical Curve("inlet:uniform:0.5") = {4};
Physical Curve("outlet") = {2};
Physical Curve("wall") = {3};
Physical Curve("interface") = {1};
Physical Curve("held") = {5, 6, 7};
