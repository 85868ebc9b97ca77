// The built-in shear-flow device (model.md section 4, one cell at (2, -0.2)) as a geometry file
// named by the convention of docs/geometry-files.md: a template for one's own device.  Run:
//   gelcell run --geometry examples/devices/shear.geo --out results/shear-file
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
Disk(5) = {2.0, -0.2, 0, d/2};      // the cell
BooleanFragments{ Surface{1}; Delete; }{ Surface{4, 5}; Delete; }

e = 1e-6;
fluid() = Surface In BoundingBox{-e, -e, -1, L + e, W + e, 1};
c1() = Surface In BoundingBox{2.0 - d/2 - e, -0.2 - d/2 - e, -1, 2.0 + d/2 + e, -0.2 + d/2 + e, 1};
gel() = Surface{:};
gel() -= {fluid(), c1()};

inlet() = Curve In BoundingBox{-e, -e, -1, e, W + e, 1};
outlet() = Curve In BoundingBox{L - e, -e, -1, L + e, W + e, 1};
iface() = Curve In BoundingBox{1 - e, -e, -1, 3 + e, e, 1};
walls() = Curve In BoundingBox{-e, -e, -1, L + e, W + e, 1};
walls() -= {inlet(), outlet(), iface()};
b1() = Curve In BoundingBox{2.0 - d/2 - e, -0.2 - d/2 - e, -1, 2.0 + d/2 + e, -0.2 + d/2 + e, 1};
held() = Curve In BoundingBox{1 - e, -R, -1, 3 + e, e, 1};
held() -= {iface(), b1()};

Physical Surface("fluid") = fluid();
Physical Surface("gel") = gel();
Physical Surface("cell") = c1();
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
Field[3].CurvesList = {b1()};
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
