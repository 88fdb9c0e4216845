"""Read a pmpm grid frame (.vti) with VTK's own reader and check that it holds the fields
docs/deck.md names, with one value (or 3, or 9) per node.

    python scripts/check_vti.py OUTDIR/frames/grid_000001.vti

Needs the `vtk` package (pip install vtk). Exit status 0 when every field is there.
"""
import sys

import vtk  # type: ignore[import-not-found]

FIELDS = {
    "mass": 1,
    "velocity": 3,
    "pressure": 1,
    "volume_fraction": 1,
    "density": 1,
    "strain_rate": 9,
    "shear_rate": 1,
    "stress": 9,
}


def main(path: str) -> int:
    reader = vtk.vtkXMLImageDataReader()
    reader.SetFileName(path)
    reader.Update()
    image = reader.GetOutput()
    nodes = image.GetNumberOfPoints()
    if nodes == 0:
        print(f"{path}: no nodes")
        return 1
    data = image.GetPointData()
    bad = []
    for name, comps in FIELDS.items():
        a = data.GetArray(name)
        if a is None:
            bad.append(f"{name} missing")
        elif a.GetNumberOfComponents() != comps or a.GetNumberOfTuples() != nodes:
            bad.append(f"{name}: {a.GetNumberOfTuples()} x {a.GetNumberOfComponents()}")
    dims = image.GetDimensions()
    print(f"{path}: {dims[0]} x {dims[1]} x {dims[2]} nodes, spacing {image.GetSpacing()[0]}, "
          f"fields {[data.GetArrayName(i) for i in range(data.GetNumberOfArrays())]}")
    for b in bad:
        print(f"  {b}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
