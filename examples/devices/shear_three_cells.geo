// The shear-flow device of model.md section 4 with three cells at different depths,
// named by the convention of docs/geometry-files.md.  Run:
//   gelcell run --geometry examples/devices/shear_three_cells.geo --out results/shear3
SetFactory("OpenCASCADE");

L = 4; W = 0.2;                     // channel [0, L] x [0, W]
theta = Pi/3; c = 2;                // chamber: chord y = 0, x in [1, 3], bowl of half-angle theta
R = 0.5*c/Sin(theta); yb = R*Cos(theta);
d = 0.06;                           // cell diameter
h_far = 0.08; h_layer = 0.016; h_cell = d*Pi/24;   // element sizes (scaled by --mesh-size)

Rectangle(1) = {0, 0, 0, L, W};
Disk(2) = {2, yb, 0, R};
Rectangle(3) = {2 - 2*R, -2*R, 0, 4*R, 2*R};
BooleanIntersection(4) = { Surface{2}; Delete; }{ Surface{3}; Delete; };
Disk(5) = {1.8, -0.12, 0, d/2};     // three cells: shallow, middle, deep
Disk(6) = {2.0, -0.25, 0, d/2};
Disk(7) = {2.2, -0.40, 0, d/2};
BooleanFragments{ Surface{1}; Delete; }{ Surface{4, 5, 6, 7}; Delete; }

e = 1e-6;
fluid() = Surface In BoundingBox{-e, -e, -1, L + e, W + e, 1};
c1() = Surface In BoundingBox{1.8 - d/2 - e, -0.12 - d/2 - e, -1, 1.8 + d/2 + e, -0.12 + d/2 + e, 1};
c2() = Surface In BoundingBox{2.0 - d/2 - e, -0.25 - d/2 - e, -1, 2.0 + d/2 + e, -0.25 + d/2 + e, 1};
c3() = Surface In BoundingBox{2.2 - d/2 - e, -0.40 - d/2 - e, -1, 2.2 + d/2 + e, -0.40 + d/2 + e, 1};
gel() = Surface{:};
gel() -= {fluid(), c1(), c2(), c3()};

inlet() = Curve In BoundingBox{-e, -e, -1, e, W + e, 1};
outlet() = Curve In BoundingBox{L - e, -e, -1, L + e, W + e, 1};
iface() = Curve In BoundingBox{1 - e, -e, -1, 3 + e, e, 1};
walls() = Curve In BoundingBox{-e, -e, -1, L + e, W + e, 1};
walls() -= {inlet(), outlet(), iface()};
b1() = Curve In BoundingBox{1.8 - d/2 - e, -0.12 - d/2 - e, -1, 1.8 + d/2 + e, -0.12 + d/2 + e, 1};
b2() = Curve In BoundingBox{2.0 - d/2 - e, -0.25 - d/2 - e, -1, 2.0 + d/2 + e, -0.25 + d/2 + e, 1};
b3() = Curve In BoundingBox{2.2 - d/2 - e, -0.40 - d/2 - e, -1, 2.2 + d/2 + e, -0.40 + d/2 + e, 1};
held() = Curve In BoundingBox{1 - e, -R, -1, 3 + e, e, 1};
held() -= {iface(), b1(), b2(), b3()};

Physical Surface("fluid") = fluid();
Physical Surface("gel") = gel();
Physical Surface("cell_1") = c1();
Physical Surface("cell_2") = c2();
Physical Surface("cell_3") = c3();
Physical Curve("inlet:parabolic:1") = inlet();     // plane Poiseuille, maximum V0
Physical Curve("outlet") = outlet();
Physical Curve("wall") = walls();
Physical Curve("interface") = iface();
Physical Curve("held") = held();

// sizes: fine along the interface, the bowl (Brinkman layer) and the cells, coarse far away
Field[1] = Distance;
Field[1].CurvesList = {iface(), held()};
Field[1].NumPointsPerCurve = 400;
Field[2] = Threshold;
Field[2].InField = 1; Field[2].SizeMin = h_layer; Field[2].SizeMax = h_far;
Field[2].DistMin = 0.03; Field[2].DistMax = 0.5;
Field[3] = Distance;
Field[3].CurvesList = {b1(), b2(), b3()};
Field[3].NumPointsPerCurve = 100;
Field[4] = Threshold;
Field[4].InField = 3; Field[4].SizeMin = h_cell; Field[4].SizeMax = h_far;
Field[4].DistMin = 0.5*d; Field[4].DistMax = 0.5;
Field[5] = Min;
Field[5].FieldsList = {2, 4};
Background Field = 5;
Mesh.MeshSizeExtendFromBoundary = 0;
Mesh.MeshSizeFromPoints = 0;
Mesh.MeshSizeFromCurvature = 0;
