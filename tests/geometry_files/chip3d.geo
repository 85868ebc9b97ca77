// A small 3D device (tests/test_geometry_files_3d.py): a channel over a gel block, the lower half
// of a chip of height 0.4 (floor z = 0 a wall, mid-height z = 0.2 a symmetry plane), a spherical
// cell in the gel.
SetFactory("OpenCASCADE");
L = 2; W = 0.2; top = 0.2; d = 0.06;
Box(1) = {0, 0, 0, L, W, top};                 // the channel
Box(2) = {0.5, -0.3, 0, 1, 0.3, top};          // the gel
Sphere(3) = {1, -0.15, 0.1, d/2};              // the cell
BooleanFragments{ Volume{1}; Delete; }{ Volume{2, 3}; Delete; }

e = 1e-6;
fluid() = Volume In BoundingBox{-e, -e, -e, L + e, W + e, top + e};
cell() = Volume In BoundingBox{1 - d, -0.15 - d, 0.1 - d, 1 + d, -0.15 + d, 0.1 + d};
gel() = Volume{:};
gel() -= {fluid(), cell()};
inlet() = Surface In BoundingBox{-e, -e, -e, e, W + e, top + e};
outlet() = Surface In BoundingBox{L - e, -e, -e, L + e, W + e, top + e};
iface() = Surface In BoundingBox{0.5 - e, -e, -e, 1.5 + e, e, top + e};
mid() = Surface In BoundingBox{-1, -1, top - e, L + 1, W + 1, top + e};
channel() = Surface In BoundingBox{-e, -e, -e, L + e, W + e, top + e};
walls() = channel();
walls() -= {inlet(), outlet(), iface(), mid()};
block() = Surface In BoundingBox{0.5 - e, -0.3 - e, -e, 1.5 + e, e, top + e};
sphere() = Surface In BoundingBox{1 - d, -0.15 - d, 0.1 - d, 1 + d, -0.15 + d, 0.1 + d};
held() = block();
held() -= {iface(), mid(), sphere()};

Physical Volume("fluid") = fluid();
Physical Volume("gel") = gel();
Physical Volume("cell") = cell();
Physical Surface("inlet") = inlet();
Physical Surface("outlet") = outlet();
Physical Surface("wall") = walls();
Physical Surface("interface") = iface();
Physical Surface("held") = held();
Physical Surface("symmetry") = mid();

Mesh.MeshSizeMax = 0.1;
MeshSize{ PointsOf{ Volume{cell()}; } } = d/4;
