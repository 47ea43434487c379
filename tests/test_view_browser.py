"""``shellsim view`` in a real browser: Debian's Chromium, headless, WebGL in software (tests/browser.py).

A rod asset (hand-made cage and collision surface: nothing is built) on the ground of a scene file, its
lower end pinned. The page is loaded, the camera put where the test knows it, and the pixels, the
buttons and a click on the body checked against the scene."""

from __future__ import annotations

import numpy as np
import pytest
from browser import chromium, screenshot, wait_for
from test_cli_runs import rod_asset

from shellsim.shot.file import read_scene

pytest.importorskip("viser")
pytest.importorskip("selenium")

pytestmark = pytest.mark.slow

SCENE = """# a rod standing on the ground, pinned at its foot
[world]
frames = 6
substeps = 2

[[body]]
name = "rod"
asset = "{asset}"
size = 0.3
position = [0, 0, 0]

[[action]]  # its foot held
kind = "pin"
body = "rod"
region = "z<10%"
"""
#: The rod's colour on the page (the first mesh-body colour: its field is a placeholder, so no field colours).
BLUE = np.array([0.25, 0.50, 0.80]) * 255


@pytest.fixture
def shot(tmp_path):
    asset = rod_asset(tmp_path / "rod")
    path = tmp_path / "shot.toml"
    path.write_text(SCENE.format(asset=asset))
    return path


@pytest.fixture
def block_shot(tmp_path, monkeypatch):
    """The same shot with a 0.3 m block (a closed box mesh) for the rod: its cages, live ones included, are
    a 48-tet Kuhn box (no fTetWild), its collision surface the mesh itself."""
    import types

    import trimesh
    from meshes import kuhn_grid

    trimesh.creation.box((1, 1, 1)).export(tmp_path / "block.stl")

    def build_cage(outer, inner, config=None, what=""):
        verts, tets, _ = kuhn_grid(0.0, 1.0, 2)
        return types.SimpleNamespace(vertices=verts + outer.bounds[0], tets=tets)

    monkeypatch.setattr("shellsim.tetcage.build.build_cage", build_cage)
    path = tmp_path / "block.toml"
    text = SCENE.replace(
        'name = "rod"\nasset = "{asset}"', 'name = "rod"\nmesh = "block.stl"\nmaterial = "jelly"'
    )
    path.write_text(text.replace("substeps = 2", "substeps = 2\ngravity = 0"))
    return path


@pytest.fixture
def page(request):
    """(viewer, browser, client) on the shot the test names (``shot`` or ``block_shot``), the browser's
    camera looking straight at the body from the side."""
    from shellsim.view.viewer import Viewer

    shot = request.getfixturevalue(getattr(request, "param", "shot"))
    viewer = Viewer(port=0, colors=False, picture=False).open(shot)
    driver = chromium(800, 600)
    try:
        driver.get(viewer.url)
        client = wait_for(lambda: next(iter(viewer.server.get_clients().values()), None), 30, "a client")
        wait_for(
            lambda: driver.execute_script("return document.querySelectorAll('canvas').length"), 30, "canvas"
        )
        with client.atomic():
            client.camera.up_direction = (0.0, 0.0, 1.0)
            client.camera.position = (0.0, -1.2, 0.15)
            client.camera.look_at = (0.0, 0.0, 0.15)
        yield viewer, driver, client
    finally:
        driver.quit()
        viewer.close()


def _button(driver, text: str):
    from selenium.webdriver.common.by import By

    return wait_for(lambda: driver.find_elements(By.XPATH, f"//button[contains(., '{text}')]"), 20, text)[0]


def _settled_image(driver, path, previous=None):
    """A screenshot taken once two in a row agree (the page has drawn the camera it was given)."""

    def same():
        nonlocal previous
        image = screenshot(driver, path)
        done = previous is not None and np.abs(image.astype(int) - previous).mean() < 0.5
        previous = image.astype(int)
        return (image,) if done else None

    return wait_for(same, 30, "a still page", every=1.0)[0]


def test_the_page_shows_the_body_where_the_scene_puts_it_on_the_ground(page, tmp_path):
    """The rod (0.3 m tall, standing at the origin) is seen from the side at the image's centre column in
    its colour; beside it, low in the image, the ground's grey checker; the canvas is not blank."""
    viewer, driver, _ = page
    image = _settled_image(driver, tmp_path / "page.png").astype(float)
    h, w, _ = image.shape
    assert image.std() > 10  # not a blank canvas
    column = image[int(0.45 * h) : int(0.55 * h), w // 2 - 3 : w // 2 + 3].reshape(-1, 3)
    blue = np.linalg.norm(column - BLUE, axis=1) < 90  # shaded, but the rod's hue
    assert blue.mean() > 0.9
    ground = image[int(0.85 * h) :, : w // 4].reshape(-1, 3)
    grey = (ground.max(axis=1) - ground.min(axis=1) < 25) & (ground.mean(axis=1) > 100)
    assert grey.mean() > 0.8


def test_simulate_streams_frames_onto_the_timeline(page):
    viewer, driver, _ = page
    assert viewer.n_frames <= 1
    _button(driver, "Simulate").click()
    wait_for(lambda: viewer.n_frames >= 6, 180, "the simulated frames on the timeline")
    viewer.frame(viewer.n_frames - 1)


@pytest.mark.parametrize("page", ["block_shot"], indirect=True)
def test_a_click_on_the_body_starts_a_poke_that_pulls_it_and_a_release_lets_it_spring_back(page):
    """Live mode (a jelly block, its foot pinned, no gravity): a click at the image centre picks the block's
    surface there; the target dragged 10 cm along +x pulls the picked point along +x; released, the block
    swings back."""
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    viewer, driver, _ = page
    viewer.start_live()
    live = wait_for(lambda: viewer.live, 60, "live mode")
    canvas = driver.find_elements(By.TAG_NAME, "canvas")[0]
    ActionChains(driver).move_to_element(canvas).click().perform()
    spring = wait_for(live.spring, 20, "a poke started by the click")
    picked, target = spring
    assert abs(picked[0]) < 0.05 and abs(picked[2] - 0.15) < 0.05  # on the block, at the image's centre
    live.move(target + [0.05, 0.0, 0.0])
    moved = wait_for(
        lambda: (p := live.spring()) is not None and p[0][0] - picked[0] > 0.01 and p, 60, "pulled"
    )
    far = moved[0][0] - picked[0]
    viewer.release()

    def back():
        state = live.positions()
        return state is not None and np.asarray(viewer.displayed("rod"))[:, 0].max() < 0.5 * far + 0.15

    wait_for(back, 60, "springing back")


def test_camera_from_this_view_and_save_write_a_file_read_scene_accepts(page, shot):
    viewer, driver, _ = page
    before = read_scene(shot)
    _button(driver, "Camera from this view").click()
    wait_for(lambda: viewer._editor is not None, 20, "the camera edit")
    _button(driver, "Save the scene file").click()
    wait_for(lambda: len(read_scene(shot).cameras) == 1, 20, "the saved camera")
    after = read_scene(shot)
    camera = after.cameras[0]
    assert camera.kind == "fixed"
    np.testing.assert_allclose(camera.position, (0.0, -1.2, 0.15), atol=1e-3)
    assert after.bodies == before.bodies and after.actions == before.actions
    assert shot.read_text().startswith("# a rod standing on the ground")  # comments kept
