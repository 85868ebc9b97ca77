// The shear-flow device of examples/devices/shear.geo extruded over a small height h, with floor
// and top as symmetry planes and the cell a cylinder through the height: the slab of model.md
// section 10.  Its solution does not depend on z and equals the planar device's (a verification
// case: tests/test_geometry_files_3d.py).  Run:
//   gelcell run --geometry examples/devices/shear_slab_cylinder.geo --kinematics small --out results/slab
SetFactory("OpenCASCADE");

L = 4; W = 0.2;                     // channel [0, L] x [0, W]
theta = Pi/3; c = 2;                // chamber: chord y = 0, x in [1, 3], bowl of half-angle theta
R = 0.5*c/Sin(theta); yb = R*Cos(theta);
d = 0.06;                           // cell diameter
h = 0.05;                           // the slab's height (the solution does not depend on it)
h_far = 0.08; h_layer = 0.016; h_cell = d*Pi/24;   // element sizes (scaled by --mesh-size)

Rectangle(1) = {0, 0, 0, L, W};
Disk(2) = {2, yb, 0, R};
Rectangle(3) = {2 - 2*R, -2*R, 0, 4*R, 2*R};
BooleanIntersection(4) = { Surface{2}; Delete; }{ Surface{3}; Delete; };
Disk(5) = {2.0, -0.2, 0, d/2};      // the cell's cross-section
BooleanFragments{ Surface{1}; Delete; }{ Surface{4, 5}; Delete; }

e = 1e-6;
iface() = Curve In BoundingBox{1 - e, -e, -1, 3 + e, e, 1};
held() = Curve In BoundingBox{1 - e, -R, -1, 3 + e, e, 1};
b1() = Curve In BoundingBox{2.0 - d/2 - e, -0.2 - d/2 - e, -1, 2.0 + d/2 + e, -0.2 + d/2 + e, 1};
held() -= {iface(), b1()};

// sizes of the planar mesh (the floor's), as in shear.geo; through the height, layers of prisms
// split into tetrahedra, about h_layer thick (not scaled by --mesh-size: the solution does not
// depend on z, but one layer leaves the pressures offset by 2e-4 relative, not shrinking)
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

Extrude {0, 0, h} { Surface{:}; Layers{Ceil(h/h_layer)}; }

fluid() = Volume In BoundingBox{-e, -e, -e, L + e, W + e, h + e};
c1() = Volume In BoundingBox{2.0 - d/2 - e, -0.2 - d/2 - e, -e, 2.0 + d/2 + e, -0.2 + d/2 + e, h + e};
gel() = Volume{:};
gel() -= {fluid(), c1()};

inlet() = Surface In BoundingBox{-e, -e, -e, e, W + e, h + e};
outlet() = Surface In BoundingBox{L - e, -e, -e, L + e, W + e, h + e};
faces() = Surface In BoundingBox{1 - e, -e, -e, 3 + e, e, h + e};      // the chord y = 0 under the channel
sym() = Surface In BoundingBox{-1, -2, -e, L + 1, W + e, e};            // the floor z = 0
top() = Surface In BoundingBox{-1, -2, h - e, L + 1, W + e, h + e};     // the top z = h
sym() += top();
channel() = Surface In BoundingBox{-e, -e, -e, L + e, W + e, h + e};
walls() = channel();
walls() -= {inlet(), outlet(), faces(), sym()};
cyl() = Surface In BoundingBox{2.0 - d/2 - e, -0.2 - d/2 - e, -e, 2.0 + d/2 + e, -0.2 + d/2 + e, h + e};
cyl() -= {sym()};
bowl() = Surface In BoundingBox{1 - e, -R, -e, 3 + e, e, h + e};
bowl() -= {faces(), sym(), cyl()};

Physical Volume("fluid") = fluid();
Physical Volume("gel") = gel();
Physical Volume("cell") = c1();
Physical Surface("inlet:parabolic:1") = inlet();   // plane Poiseuille across the channel, uniform in z
Physical Surface("outlet") = outlet();
Physical Surface("wall") = walls();
Physical Surface("interface") = faces();
Physical Surface("held") = bowl();
Physical Surface("symmetry") = sym();
