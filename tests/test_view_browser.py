"""The grasp pages in a real browser: the mesh and the grasps are drawn in one frame.

Headless Chromium opens each page (plotly's 3-D scene is WebGL, rendered in software by
SwiftShader) after a script appended to a copy of it recolours the scene: the mesh opaque and
unlit pure blue, the successful grasps pure red, everything else hidden, the camera looking
along +y with an orthographic projection. The object is a 6 x 10 cm cylinder whose file is
centred on the origin; its grasps are side grasps at a third, half and two thirds of its height
in the object's frame (stood on z = 0), so where the pages are right the red pixels' median is
the centre of the blue pixels' box. The companion draws the mesh as the file reads (what
``python -m jaxgrasp.view --mesh`` did): the median moves to the box's top edge and the check
must say so.

Outside CI the tests skip when Chromium is missing; ``.ci/run`` installs it and sets
``JAXGRASP_REQUIRE_BROWSER=1``, which turns the skip into a failure.
"""

import html
import json
import os
import re
import shutil
import subprocess

import matplotlib.image
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import jaxgrasp as jg
from jaxgrasp import view
from jaxgrasp.learn import __main__ as learn_cli
from jaxgrasp.learn.files.results import LearnResult
from jaxgrasp.learn.setup.demos import Demos

#: Headless, as root, offline; --enable-unsafe-swiftshader opts in to software WebGL (without
#: it Chromium still falls back to SwiftShader today but logs that the fallback is deprecated).
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--window-size=640,640",
         "--virtual-time-budget=1000")
MESH_RGB, GRASP_RGB = (0, 0, 255), (255, 0, 0)
#: Appended to a copy of the page: recolour, hide the rest, look along +y (z up), no perspective.
RECOLOUR = """<script>
window.addEventListener('load', function () {
  var gd = document.querySelector('.plotly-graph-div');
  var data = gd.data.map(function (t) {
    t = Object.assign({}, t);
    if (t.type === 'mesh3d') {
      Object.assign(t, {color: 'rgb(@MESH@)', opacity: 1, lighting: {ambient: 1, diffuse: 0,
                        specular: 0, fresnel: 0, roughness: 1}});
    } else if (String(t.name).indexOf('success') === 0) {
      t.line = Object.assign({}, t.line, {color: 'rgb(@GRASP@)'});
    } else {
      t.visible = false;
    }
    return t;
  });
  var hide = {visible: false};
  var layout = Object.assign({}, gd.layout, {showlegend: false, title: {text: ''}});
  layout.scene = Object.assign({}, gd.layout.scene, {xaxis: hide, yaxis: hide, zaxis: hide,
    camera: {eye: {x: 0, y: -2, z: 0}, up: {x: 0, y: 0, z: 1},
             projection: {type: 'orthographic'}}});
  Plotly.react(gd, data, layout, {displayModeBar: false});
});
</script>""".replace("@MESH@", ",".join(map(str, MESH_RGB))).replace(
    "@GRASP@", ",".join(map(str, GRASP_RGB)))
#: Drawn together: the red median lies within half the blue box's half-size of its centre.
MAX_OFFSET = 0.5


@pytest.fixture(scope="module")
def chromium():
    path = shutil.which("chromium") or ("/usr/bin/chromium"
                                        if os.access("/usr/bin/chromium", os.X_OK) else None)
    if path is None:
        why = ("no Chromium (install it: apt-get install chromium); the browser check of the "
               "grasp pages needs it")
        if os.environ.get("JAXGRASP_REQUIRE_BROWSER"):
            pytest.fail(f"JAXGRASP_REQUIRE_BROWSER is set but there is {why}")
        pytest.skip(why)
    return path


@pytest.fixture(scope="module")
def cylinder(tmp_path_factory):
    """A 6 x 10 cm cylinder centred on the origin, as a user's STL file."""
    path = tmp_path_factory.mktemp("mesh") / "cylinder.stl"
    trimesh.creation.cylinder(radius=0.03, height=0.1).export(path)
    return path


def side_grasps(obj) -> LearnResult:
    """A run whose successes are 12 side grasps of ``obj`` (approach horizontal, towards its
    axis, from 4 directions) at a third, half and two thirds of its height."""
    height = float(obj.mesh.bounds[1, 2])
    poses = []
    for angle in np.deg2rad([0, 90, 180, 270]):
        approach = np.array([np.cos(angle), np.sin(angle), 0.0])
        closing = np.array([-np.sin(angle), np.cos(angle), 0.0])
        rot = np.stack([np.cross(closing, approach), closing, approach], axis=1)
        q = Rotation.from_matrix(rot).as_quat(scalar_first=True)
        poses += [[0.0, 0.0, f * height, *q] for f in (1 / 3, 1 / 2, 2 / 3)]
    pos = np.asarray(poses, np.float32)[:, None, :]
    n = len(pos)
    outcomes = np.zeros((n, 1), np.int8)
    return LearnResult(
        object_name=obj.name, object_hash=obj.content_hash, workflow="active",
        method="kameleon_darting", sketch="biased", modes_kind="demos", seed=0,
        backend="mujoco", params=jg.learn.LearnParams(iterations=n - 1, burn_in=1),
        positions=pos, proposals=pos, outcomes=outcomes,
        epsilons=np.full((n, 1), 0.1, np.float32), accepted=outcomes == 0,
        is_jump=np.zeros((n, 1), bool), initial_positions=pos[0], modes=pos[0],
        sketch_points=pos[:, 0], demos=Demos(pos[:2, 0], None))


@pytest.fixture(scope="module")
def pages(cylinder, tmp_path_factory):
    """The pages that ship for a run on the cylinder: ``python -m jaxgrasp.view RUN --mesh``
    and the learn command's ``grasps.html`` (its learning replaced by the run above); and the
    companion, the mesh drawn as the file reads."""
    tmp = tmp_path_factory.mktemp("pages")
    result = side_grasps(jg.objects.from_mesh(cylinder, cache=False))
    result.save(tmp / "run")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("XDG_CACHE_HOME", str(tmp / "cache"))
        assert view.main([str(tmp / "run"), "--mesh", str(cylinder),
                          "--out", str(tmp / "view.html")]) == 0
        mp.setattr(learn_cli, "load_scene", lambda obj, gripper: obj)
        mp.setattr(learn_cli, "Simulator", lambda scene, batch_size: None)
        mp.setattr(learn_cli, "active", lambda obj, **_: side_grasps(obj))
        argv = [str(cylinder), "--quiet", "--out", str(tmp / "learn")]
        if "--robust-tries" in learn_cli.parser().format_help():
            argv += ["--robust-tries", "0"]  # no physics: the page is what is checked here
        assert learn_cli.main(argv) == 0
    view.view_html(result, trimesh.load(cylinder, force="mesh"), tmp / "as_read.html")
    return {"view": tmp / "view.html", "learn": tmp / "learn" / "grasps.html",
            "as_read": tmp / "as_read.html"}


def screenshot(chromium, page, tmp_path):
    """The recoloured page in headless Chromium: an (H, W, 3) uint8 image, and its PNG."""
    copy = tmp_path / f"{page.stem}_recoloured.html"
    copy.write_text(page.read_text().replace("</body>", RECOLOUR + "</body>", 1))
    png = tmp_path / f"{page.stem}.png"
    run = subprocess.run([chromium, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}",
                          f"--screenshot={png}", copy.as_uri()],
                         capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and png.exists(), f"chromium failed:\n{run.stderr[-2000:]}"
    return np.round(matplotlib.image.imread(png)[..., :3] * 255).astype(int), png


def grasp_offset(img, png) -> np.ndarray:
    """(x, y): the grasp pixels' median from the centre of the mesh pixels' box, in units of
    the box's half-size (y down; inside the box: both within +-1)."""
    def mask(rgb):
        return (np.abs(img - np.asarray(rgb)) < 60).all(axis=-1)

    mesh, grasp = np.argwhere(mask(MESH_RGB)), np.argwhere(mask(GRASP_RGB))
    assert len(mesh) > 1000, f"{png}: the mesh is not drawn (WebGL did not render?)"
    assert len(grasp) > 100, f"{png}: the grasps are not drawn"
    lo, hi = mesh.min(axis=0), mesh.max(axis=0)
    return ((np.median(grasp, axis=0) - (lo + hi) / 2) / ((hi - lo) / 2))[::-1]


@pytest.mark.parametrize("page", ["view", "learn"])
def test_grasps_are_drawn_on_the_mesh(chromium, pages, page, tmp_path):
    img, png = screenshot(chromium, pages[page], tmp_path)
    offset = grasp_offset(img, png)
    assert np.abs(offset).max() < MAX_OFFSET, (
        f"{png}: the grasps' median is {offset} box half-sizes from the mesh's centre")


def test_companion_a_mesh_drawn_as_read_is_caught(chromium, pages, tmp_path):
    """The check fails for the page the view drew before: the mesh 5 cm (half its height)
    below its grasps puts their median on the mesh box's top edge."""
    img, png = screenshot(chromium, pages["as_read"], tmp_path)
    offset = grasp_offset(img, png)
    assert np.abs(offset).max() >= MAX_OFFSET
    assert offset[1] == pytest.approx(-1.0, abs=0.2)  # y is down: the top edge


#: Appended to a copy of the page: once drawn, write what the browser holds into the page.
PROBE = """<script>
window.addEventListener('load', function () {
  var gd = document.querySelector('.plotly-graph-div');
  var t = gd._fullData.filter(function (t) { return String(t.name).indexOf('success') === 0; })[0];
  var bar = document.querySelector('.colorbar');
  var out = {name: t.name, color: Array.from(t.line.color), text: Array.from(t.text || []),
             colorscale: t.line.colorscale, bar: bar ? bar.textContent : null};
  var pre = document.createElement('pre');
  pre.id = 'probe';
  pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>"""


def probe(chromium, page, tmp_path) -> dict:
    """What the page's success trace and colour bar hold once Chromium has drawn it."""
    copy = tmp_path / f"{page.stem}_probe.html"
    copy.write_text(page.read_text().replace("</body>", PROBE + "</body>", 1))
    run = subprocess.run([chromium, *FLAGS, f"--user-data-dir={tmp_path / 'profile'}",
                          "--dump-dom", copy.as_uri()], capture_output=True, text=True,
                         timeout=120)
    found = re.search(r'<pre id="probe">(.*?)</pre>', run.stdout, re.S)
    assert found, f"chromium drew no probe:\n{run.stderr[-2000:]}"
    return json.loads(html.unescape(found.group(1)))


def test_grasps_are_coloured_by_how_often_they_held(chromium, cylinder, tmp_path):
    """A run carrying robustness: each drawn grasp's colour value is its hold probability
    (most robust first), its hover text says how often it held, and the colour bar says
    "held in k of N tries under 3 mm / 3°"; without robustness none of it."""
    obj = jg.objects.from_mesh(cylinder, cache=False)
    plain = side_grasps(obj)
    held = np.arange(len(plain.grasps)) % 11
    rob = jg.learn.Robustness(plain.grasps.astype(float), held, jg.learn.PoseNoise())
    view.view_html(plain.with_robustness(rob), obj.mesh, tmp_path / "robust.html")
    view.view_html(plain, obj.mesh, tmp_path / "plain.html")
    got = probe(chromium, tmp_path / "robust.html", tmp_path)
    colors = np.asarray(got["color"], float).reshape(-1, 12)
    assert (colors == colors[:, :1]).all()  # one colour per grasp
    np.testing.assert_allclose(colors[:, 0], np.sort(held)[::-1] / 10)
    assert got["text"][0].endswith("held in 10 of 10 tries under 3 mm / 3° (100 %)")
    assert "held in k of 10 tries" in got["bar"] and "under 3 mm / 3°" in got["bar"]
    assert "8 of 10" in got["bar"] and "robust: held in >= 8 of 10" in got["name"]
    assert got["colorscale"][0][1] != got["colorscale"][-1][1]  # red to green
    plain_page = probe(chromium, tmp_path / "plain.html", tmp_path)
    assert plain_page["bar"] is None and plain_page["name"] == "success (12 distinct)"
