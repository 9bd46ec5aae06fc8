"""The renderer's OpenGL platforms: OSMesa and EGL (renderer.gl_platform, renderer.context), and how kmpipe chooses
between them (``kmpipe --gl``, a recipe's ``[line] gl``).

References: the two platforms run the same shaders, so on this machine (Mesa's llvmpipe behind both: EGL through its
surfaceless platform) a frame rendered through EGL must equal the OSMesa one to float tolerance. A process has one
platform, so EGL's frames come from a fresh interpreter.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from kmpipe.cli import main
from renderer import gl_platform, meshes
from renderer.environment import Environment
from renderer.scene import DirectionalLight, PerspectiveCamera, PointLight, Prop, Scattering, Scene
from renderer.stack import SKIN_SPECULAR, ChannelStack

TESTS = Path(__file__).resolve().parent


def scene() -> Scene:
    """A sphere of skin under a soft key and a point fill, in a graded environment, over a floor that takes its
    shadow, with subsurface scattering and 4 x multisampling: most of what the passes do."""
    sky = np.linspace(1.2, 0.2, 16)[:, None, None] * np.ones((16, 32, 3), np.float32)
    floor = meshes.card(200.0, 200.0)
    floor.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1.0, 0.0, 0.0)))
    floor.apply_transform(trimesh.transformations.translation_matrix((0.0, -30.0, 0.0)))
    return Scene(
        mesh=meshes.sphere(30.0),
        stack=ChannelStack((), (), (0.62, 0.45, 0.38)),
        camera=PerspectiveCamera(eye=(0.0, 20.0, 200.0), fov_y_deg=40.0),
        lights=[
            DirectionalLight((-0.5, -0.7, -0.5), (0.8, 0.8, 0.8), angle_deg=20.0),
            PointLight((-150.0, 50.0, 150.0), (0.2, 0.2, 0.25), 200.0),
        ],
        resolution=(96, 96),
        substrate_lobe=SKIN_SPECULAR,
        scattering=Scattering(alpha=1.0),
        props=[Prop(floor, (0.5, 0.5, 0.5))],
        environment=Environment(sky, intensity=0.7),
        multisamples=4,
    )


def _frame_through(choice: str, path: Path) -> str:
    """Render :func:`scene` with ``KMPIPE_GL=choice`` in a fresh interpreter into ``path`` (.npy); its platform."""
    code = (
        "import sys, numpy as np; sys.path.insert(0, sys.argv[1]); from test_gl_platform import scene; "
        "from renderer.skin import render_skin; from renderer import context; "
        "np.save(sys.argv[2], render_skin(scene())); print(context.renderer_name())"
    )
    done = subprocess.run([sys.executable, "-c", code, str(TESTS), str(path)], capture_output=True, text=True,
                          env={**os.environ, gl_platform.CHOICE_VARIABLE: choice}, check=True)  # fmt: skip
    return done.stdout.strip()


def test_a_frame_through_egl_equals_the_osmesa_one(tmp_path):
    from renderer.skin import render_skin

    here = render_skin(scene())
    platform = _frame_through("egl", tmp_path / "egl.npy")
    there = np.load(tmp_path / "egl.npy")
    assert platform.startswith("EGL: ")
    assert here.shape == there.shape == (96, 96, 3) and np.ptp(here) > 0.2  # lit, shadowed, on the floor
    np.testing.assert_allclose(there, here, rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize(("hardware", "platform"), [(True, "egl"), (False, "osmesa")])
def test_auto_takes_egl_where_a_hardware_device_is(hardware, platform):
    assert gl_platform.choose("auto", hardware=hardware) == platform
    assert gl_platform.choose("osmesa", hardware=True) == "osmesa"
    assert gl_platform.choose("egl", hardware=False) == "egl"


def test_the_devices_auto_counts_are_hardware_ones():
    found = gl_platform.hardware_devices()  # this machine: Mesa's software device only, or a GPU's as well
    assert all("EGL_MESA_device_software" not in names.split() for names in found)
    assert not gl_platform.is_hardware("EGL_MESA_device_software EGL_EXT_device_drm_render_node")
    assert gl_platform.is_hardware("EGL_NV_device_cuda EGL_EXT_device_drm")


def test_an_unknown_platform_is_refused_where_it_is_read(tmp_path, capsys):
    with pytest.raises(ValueError, match="KMPIPE_GL must be one of auto, osmesa, egl, got 'vulkan'"):
        gl_platform.choose("vulkan")
    done = subprocess.run([sys.executable, "-c", "import renderer.context"], capture_output=True, text=True,
                          env={**os.environ, gl_platform.CHOICE_VARIABLE: "vulkan"})  # fmt: skip
    assert done.returncode != 0 and "KMPIPE_GL must be one of auto, osmesa, egl, got 'vulkan'" in done.stderr
    with pytest.raises(SystemExit) as stopped:
        main(["--gl", "vulkan", "card", "-o", str(tmp_path / "card.png")])
    assert stopped.value.code == 2 and "--gl" in capsys.readouterr().err


def test_another_platform_than_the_process_renders_through_is_exit_2_naming_the_option(tmp_path, capsys):
    from renderer import context

    other = "egl" if context.PLATFORM == "osmesa" else "osmesa"
    status = main(["--gl", other, "card", "-o", str(tmp_path / "card.png")])
    err = capsys.readouterr().err
    assert status == 2 and "--gl" in err and "fresh process" in err
    assert not (tmp_path / "card.png").exists()


def test_a_recipe_chooses_the_platform_and_an_unknown_one_is_exit_2_naming_it(tmp_path, capsys):
    from renderer import context

    recipes = TESTS.parent / "recipes"
    for name in ("samples", "head", "scenes"):
        (tmp_path / name).symlink_to(recipes / name)
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "sessions").symlink_to(recipes / "demo" / "sessions")
    text = (recipes / "demo" / "recipe.toml").read_text(encoding="utf-8")
    path = tmp_path / "demo" / "recipe.toml"
    other = "egl" if context.PLATFORM == "osmesa" else "osmesa"
    for choice, says in (("vulkan", "'auto', 'osmesa' or 'egl'"), (other, "fresh process")):
        path.write_text(text.replace("[line]\n", f'[line]\ngl = "{choice}"\n', 1), encoding="utf-8")
        status = main(["run", str(path), "-o", str(tmp_path / "out"), "--dry-run"])
        err = capsys.readouterr().err
        assert status == 2 and "line.gl" in err and says in err, err
    path.write_text(text.replace("[line]\n", f'[line]\ngl = "{context.PLATFORM}"\n', 1), encoding="utf-8")
    try:
        assert main(["run", str(path), "-o", str(tmp_path / "out"), "--dry-run"]) == 0
        assert os.environ[gl_platform.CHOICE_VARIABLE] == context.PLATFORM  # for the workers it spawns
    finally:
        os.environ.pop(gl_platform.CHOICE_VARIABLE, None)
