"""Open a pmpm run in ParaView: the particles as point Gaussians coloured by pressure, and,
when the run wrote grid frames (formats = ["grid"]), a slice of the grid coloured by speed.

    pvpython examples/paraview_view.py OUTDIR          # renders OUTDIR/paraview.png
    paraview --script=examples/paraview_view.py        # interactive (asks nothing: set OUTDIR below)

The slice is the plane through the middle of the grid across y (the x-z plane in 3D; the
whole grid in 2D). Written for ParaView 5.10 and later (paraview.simple).
"""
import os
import sys

from paraview.simple import (  # type: ignore[import-not-found]
    ColorBy,
    GetActiveViewOrCreate,
    GetAnimationScene,
    OpenDataFile,
    Render,
    ResetCamera,
    SaveScreenshot,
    Show,
    Slice,
)

OUTDIR = sys.argv[1] if len(sys.argv) > 1 else "out/dam_break_3d"

view = GetActiveViewOrCreate("RenderView")
scene = GetAnimationScene()
scene.UpdateAnimationUsingDataTimeSteps()

particles = OpenDataFile(os.path.join(OUTDIR, "particles.pvd"))
shown = Show(particles, view)
shown.SetRepresentationType("Point Gaussian")
shown.GaussianRadius = 0.002  # m: about half the particle spacing of the shipped examples
ColorBy(shown, ("POINTS", "pressure"))
shown.RescaleTransferFunctionToDataRange(True, False)
shown.SetScalarBarVisibility(view, True)

grid_pvd = os.path.join(OUTDIR, "grid.pvd")
if os.path.exists(grid_pvd):
    grid = OpenDataFile(grid_pvd)
    bounds = grid.GetDataInformation().GetBounds()
    if bounds[4] == bounds[5]:
        cut = grid  # a 2D run: the grid is the slice
    else:
        cut = Slice(Input=grid)
        cut.SliceType = "Plane"
        cut.SliceType.Origin = [0.5 * (bounds[0] + bounds[1]), 0.5 * (bounds[2] + bounds[3]),
                                0.5 * (bounds[4] + bounds[5])]
        cut.SliceType.Normal = [0.0, 1.0, 0.0]
    sliced = Show(cut, view)
    ColorBy(sliced, ("POINTS", "velocity", "Magnitude"))
    sliced.SetScalarBarVisibility(view, True)

scene.GoToLast()
view.CameraPosition = [0.0, -5.0, 0.0]
view.CameraViewUp = [0.0, 0.0, 1.0]
ResetCamera(view)
Render(view)
if len(sys.argv) > 1:
    SaveScreenshot(os.path.join(OUTDIR, "paraview.png"), view, ImageResolution=[1280, 720])
