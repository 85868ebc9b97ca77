// Cross-section (top view) of a three-channel chip: a central gel channel held by two rows of
// posts between two media channels, named by the convention of docs/geometry-files.md.
// The upper media channel is fed at its left end and closed at its right end; the lower one is
// closed at its left end and open at its right end: the medium must cross the gel (a
// pressure-driven flow across it).  Three cells sit in the gel.  Lengths in units of L0.
// Run:  gelcell run --geometry examples/devices/three_channel_chip.geo --out results/chip
SetFactory("OpenCASCADE");

L = 3;                    // channel length
H = 1;                    // gel channel width, y in [0, H]
M = 0.4;                  // media channel width
r = 0.15;                 // post radius; posts centred on y = 0 and y = H
d = 0.08;                 // cell diameter
h_far = 0.1; h_layer = 0.025; h_cell = d*Pi/20;   // element sizes (scaled by --mesh-size)

Rectangle(1) = {0, H, 0, L, M};          // upper media channel
Rectangle(2) = {0, 0, 0, L, H};          // gel channel
Rectangle(3) = {0, -M, 0, L, M};         // lower media channel
For i In {0:2}
  Disk(11 + 2*i) = {0.5 + i, H, 0, r};
  Disk(12 + 2*i) = {0.5 + i, 0, 0, r};
EndFor
BooleanDifference{ Surface{1, 2, 3}; Delete; }{ Surface{11:16}; Delete; }
cx[] = {0.9, 1.5, 2.1}; cy[] = {0.65, 0.45, 0.3};
For k In {0:2}
  Disk(20 + k) = {cx[k], cy[k], 0, d/2};
EndFor
BooleanFragments{ Surface{:}; Delete; }{}

e = 1e-6;
up() = Surface In BoundingBox{-e, H - e, -1, L + e, H + M + e, 1};
down() = Surface In BoundingBox{-e, -M - e, -1, L + e, e, 1};
c0() = Surface In BoundingBox{cx[0] - d/2 - e, cy[0] - d/2 - e, -1, cx[0] + d/2 + e, cy[0] + d/2 + e, 1};
c1() = Surface In BoundingBox{cx[1] - d/2 - e, cy[1] - d/2 - e, -1, cx[1] + d/2 + e, cy[1] + d/2 + e, 1};
c2() = Surface In BoundingBox{cx[2] - d/2 - e, cy[2] - d/2 - e, -1, cx[2] + d/2 + e, cy[2] + d/2 + e, 1};
b0() = Curve In BoundingBox{cx[0] - d/2 - e, cy[0] - d/2 - e, -1, cx[0] + d/2 + e, cy[0] + d/2 + e, 1};
b1() = Curve In BoundingBox{cx[1] - d/2 - e, cy[1] - d/2 - e, -1, cx[1] + d/2 + e, cy[1] + d/2 + e, 1};
b2() = Curve In BoundingBox{cx[2] - d/2 - e, cy[2] - d/2 - e, -1, cx[2] + d/2 + e, cy[2] + d/2 + e, 1};
gel() = Surface{:};
gel() -= {up(), down(), c0(), c1(), c2()};

inlet() = Curve In BoundingBox{-e, H - e, -1, e, H + M + e, 1};
outlet() = Curve In BoundingBox{L - e, -M - e, -1, L + e, e, 1};
top() = Curve In BoundingBox{-e, H - e, -1, L + e, H + e, 1};     // gaps between the upper posts
bottom() = Curve In BoundingBox{-e, -e, -1, L + e, e, 1};          // gaps between the lower posts
walls() = Curve In BoundingBox{-e, H - e, -1, L + e, H + M + e, 1};
walls() += Curve In BoundingBox{-e, -M - e, -1, L + e, e, 1};
walls() -= {inlet(), outlet(), top(), bottom()};
held() = Curve In BoundingBox{-e, -e, -1, L + e, H + e, 1};
held() -= {top(), bottom(), b0(), b1(), b2()};

Physical Surface("fluid") = {up(), down()};
Physical Surface("gel") = gel();
Physical Surface("cell_1") = c0();
Physical Surface("cell_2") = c1();
Physical Surface("cell_3") = c2();
Physical Curve("inlet:parabolic:1") = inlet();
Physical Curve("outlet") = outlet();
Physical Curve("wall") = walls();
Physical Curve("interface_1") = top();
Physical Curve("interface_2") = bottom();
Physical Curve("held") = held();

Field[1] = Distance;
Field[1].CurvesList = {top(), bottom(), held()};
Field[1].NumPointsPerCurve = 200;
Field[2] = Threshold;
Field[2].InField = 1; Field[2].SizeMin = h_layer; Field[2].SizeMax = h_far;
Field[2].DistMin = 0.03; Field[2].DistMax = 0.4;
Field[3] = Distance;
Field[3].CurvesList = {b0(), b1(), b2()};
Field[3].NumPointsPerCurve = 100;
Field[4] = Threshold;
Field[4].InField = 3; Field[4].SizeMin = h_cell; Field[4].SizeMax = h_far;
Field[4].DistMin = 0.5*d; Field[4].DistMax = 0.4;
Field[5] = Min;
Field[5].FieldsList = {2, 4};
Background Field = 5;
Mesh.MeshSizeExtendFromBoundary = 0;
Mesh.MeshSizeFromPoints = 0;
Mesh.MeshSizeFromCurvature = 0;
