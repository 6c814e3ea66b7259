import pytest

from ngbet.scene import Scene


def coarse(**changes) -> Scene:
    """The paper's scene on a coarse mesh (10 mm, p = 2): seconds, not minutes."""
    base = {"discretization.mesh_size_mm": 10.0, "discretization.corner_mesh_size_mm": 0.0,
            "discretization.order_u": 2, "outputs.vtk": False, "outputs.plot": False}
    base.update(changes)
    return Scene().with_changes(**base)


@pytest.fixture
def coarse_scene():
    return coarse
