import pytest

from floaff_zoo.sim.kitchen import SceneSpec, build_scene


@pytest.fixture(scope="session")
def scene_factory():
    """build_scene with the in-process model cache (one compile per kitchen)."""
    return lambda task, layout=0, style=0, seed=0: build_scene(SceneSpec(layout, style, seed, task))
