"""Foxglove Studio 1.48's web build for the view's end-to-end test, from the npm registry.

``@foxglove/studio-base`` 1.48.0 (the last open-source Foxglove Studio, MPL-2.0) is published with
``assets/index.js``: the whole app prebuilt by webpack as a UMD library (its chunks, WebAssembly
and fonts beside it) whose only externals are ``react`` and ``react-dom``. It holds no page: a
web build is that bundle, React 17's UMD builds (``react``, ``react-dom`` 17.0.2) and a page that
mounts its ``App`` with the Foxglove WebSocket data source, as Studio's own web shell did
(:func:`write_page`). The page opens the connection from the URL (``?ds=foxglove-websocket&ds.url=``,
Studio's deep link) and the layout from ``layoutId``, held in memory by the page.

Fetched once with ``npm pack`` into ``$LIDARPKT_TEST_CACHE`` (default ``~/.cache/lidarpkt-tests``);
``python3 tests/view/foxglove_studio.py`` fetches it ahead (``.ci/run`` does). Standard library only.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

PACKAGES = {"studio-base": ("@foxglove/studio-base", "1.48.0", "assets/"),
            "react": ("react", "17.0.2", "umd/"), "react-dom": ("react-dom", "17.0.2", "umd/")}
BUILD = "foxglove-studio-1.48.0-web"
INSTALL = ("apt-get install chromium nodejs npm (Debian's Chromium; npm fetches Foxglove Studio 1.48's web build) "
           "and pip install playwright (the test extra; no browser download: the system's Chromium is used)")


class Unavailable(Exception):
    """The web build cannot be had here (no npm, no registry): the test says how to get it."""


def cache_dir() -> Path:
    return Path(os.environ.get("LIDARPKT_TEST_CACHE") or Path.home() / ".cache" / "lidarpkt-tests")


def web_build(cache: Path | None = None) -> Path:
    """The folder holding ``studio-base/assets``, ``react/umd`` and ``react-dom/umd``; fetched with
    ``npm pack`` when absent. Raises :class:`Unavailable`."""
    root = (cache or cache_dir()) / BUILD
    if (root / ".complete").exists():
        return root
    npm = shutil.which("npm")
    if npm is None:
        raise Unavailable("npm is not installed")
    root.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=root.parent, prefix=f".{BUILD}-") as tmp:
        specs = [f"{name}@{version}" for name, version, _ in PACKAGES.values()]
        try:
            run = subprocess.run([npm, "pack", "--silent", *specs, "--pack-destination", tmp], capture_output=True,
                                 text=True, timeout=600)
        except subprocess.TimeoutExpired:
            raise Unavailable(f"npm pack {' '.join(specs)} timed out") from None
        if run.returncode != 0:
            raise Unavailable(f"npm pack {' '.join(specs)} failed: {run.stderr.strip()[-500:]}")
        staged = Path(tmp) / "build"
        for folder, (name, version, keep) in PACKAGES.items():
            tgz = Path(tmp) / f"{name.lstrip('@').replace('/', '-')}-{version}.tgz"
            with tarfile.open(tgz) as tar:
                members = [m for m in tar.getmembers() if m.name.startswith(f"package/{keep}") and m.isfile()]
                for m in members:
                    m.name = m.name[len("package/"):]
                safe = {"filter": "data"} if hasattr(tarfile, "data_filter") else {}  # Python >= 3.11.4
                tar.extractall(staged / folder, members=members, **safe)
        for script in (staged / "studio-base" / "assets").glob("*.js"):
            _drop_inline_source_map(script)
        (staged / ".complete").write_text("\n".join(f"{n}@{v}" for n, v, _ in PACKAGES.values()) + "\n")
        shutil.rmtree(root, ignore_errors=True)
        os.replace(staged, root)
    return root


def _drop_inline_source_map(script: Path) -> None:
    """Cut a script's trailing inline source map (``//# sourceMappingURL=data:...``): a browser running
    the app never reads it, and in this package it is 60 % of the bytes it would parse."""
    text = script.read_bytes()
    cut = text.rfind(b"\n//# sourceMappingURL=data:")
    if cut >= 0:
        script.write_bytes(text[:cut + 1])


def layout(layout_id: str, topic: str, frame_id: str) -> dict:
    """A layout of one 3D panel showing ``topic`` (a point cloud: hidden by default in Studio's 3D
    panel) on a black background, following ``frame_id``, without the grid (so that coloured pixels
    are the cloud's)."""
    panel = "3D!lidarpkt"
    data = {
        "configById": {panel: {
            "followTf": frame_id,
            "scene": {"backgroundColor": "#000000", "transforms": {"showLabel": False}},
            "layers": {},
            "topics": {topic: {"visible": True, "pointSize": 4}},
            "cameraState": {"distance": 40, "perspective": True, "phi": 60, "thetaOffset": 45, "targetOffset": [0, 0, 0],
                            "target": [0, 0, 0], "targetOrientation": [0, 0, 0, 1], "fovy": 45, "near": 0.5,
                            "far": 5000},
        }},
        "globalVariables": {}, "userNodes": {}, "playbackConfig": {"speed": 1},
        "layout": panel,
    }
    return {"id": layout_id, "name": "lidarpkt view", "permission": "CREATOR_WRITE",
            "baseline": {"data": data, "savedAt": "2026-01-01T00:00:00.000Z"}, "working": None, "syncInfo": None}


_BOOT = """
// Foxglove Studio's web shell, reduced: in-memory settings and layouts, the WebSocket data source.
class MemoryConfiguration {
  constructor() { this.values = new Map(); this.listeners = new Map(); }
  get(key) { return this.values.get(key); }
  async set(key, value) {
    this.values.set(key, value);
    for (const cb of this.listeners.get(key) ?? []) cb(value);
  }
  addChangeListener(key, cb) { this.listeners.set(key, [...(this.listeners.get(key) ?? []), cb]); }
  removeChangeListener(key, cb) { this.listeners.set(key, (this.listeners.get(key) ?? []).filter((f) => f !== cb)); }
}
class MemoryLayouts {
  constructor(layouts) { this.layouts = new Map(layouts.map((l) => [l.id, l])); }
  async list() { return [...this.layouts.values()]; }
  async get(_namespace, id) { return this.layouts.get(id); }
  async put(_namespace, layout) { this.layouts.set(layout.id, layout); return layout; }
  async delete(_namespace, id) { this.layouts.delete(id); }
  async importLayouts() {}
}
window.react = React;
window["react-dom"] = ReactDOM;
"""

_MOUNT = """
ReactDOM.render(
  React.createElement(App, {
    deepLinks: [window.location.href],
    appConfiguration: new MemoryConfiguration(),
    dataSources: [new FoxgloveWebSocketDataSourceFactory()],
    layoutStorage: new MemoryLayouts(LAYOUTS),
    extensionLoaders: [],
    enableGlobalCss: true,
  }),
  document.getElementById("root"),
);
"""


def write_page(folder: Path, build: Path, layouts: list[dict]) -> Path:
    """``folder/index.html`` loading React 17, the studio-base bundle (its exports become globals: a UMD
    library without a module system) and mounting its ``App``; the build linked beside it."""
    for name in PACKAGES:
        link = folder / name
        if not link.exists():
            link.symlink_to(build / name, target_is_directory=True)
    (folder / "boot.js").write_text(_BOOT)
    (folder / "mount.js").write_text(f"const LAYOUTS = {json.dumps(layouts)};\n{_MOUNT}")
    page = folder / "index.html"
    page.write_text(
        "<!doctype html>\n<html><head><meta charset='utf-8'><title>Foxglove Studio 1.48</title></head>\n"
        "<body style='margin:0'><div id='root' style='width:100vw;height:100vh'></div>\n"
        "<script src='react/umd/react.production.min.js'></script>\n"
        "<script src='react-dom/umd/react-dom.production.min.js'></script>\n"
        "<script src='boot.js'></script>\n"
        "<script src='studio-base/assets/index.js'></script>\n"
        "<script src='mount.js'></script>\n</body></html>\n")
    return page


if __name__ == "__main__":  # fetch ahead (.ci/run)
    try:
        print(web_build())
    except Unavailable as exc:
        print(f"foxglove_studio: {exc}", file=sys.stderr)
        sys.exit(1)
