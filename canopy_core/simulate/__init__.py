"""Synthetic RGB-D captures of apple trees in an orchard row, as a Kinect v2 (or, with other intrinsics,
an Azure Kinect depth mode) would record them.

Each capture is a folder in the format canopy-capture/1 plus ``ground_truth.json`` (the tree's exact height,
width, crown thickness and crown base, and every view's camera pose). Modules: :mod:`.mesh` holds the
triangle meshes, :mod:`.tree` grows trees, :mod:`.ground` and :mod:`.scene` lay out the orchard,
:mod:`.scenario` picks a scenario family and dresses the orchard with :mod:`.palette` (floors beyond green
grass, fallen leaves), :mod:`.fruit` (apples), :mod:`.trellis` (wires) and :mod:`.weeds`,
:mod:`.camera` models the sensors' cameras, :mod:`.placement` puts the balls and cameras,
:mod:`.raycast` and :mod:`.sensor` render depth and colour, :mod:`.writer` writes the folder and
:mod:`.simulator` runs it all from one seed.
"""

from canopy_core.simulate.placement import NoLayout
from canopy_core.simulate.scenario import Scenario
from canopy_core.simulate.simulator import simulate_capture, simulate_captures

__all__ = ["NoLayout", "Scenario", "simulate_capture", "simulate_captures"]
