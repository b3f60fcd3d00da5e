"""Independent BVH readers for the tests: bvhio (PyPI) and three.js's BVHLoader run by Node.

Each returns the world position of every named joint in every frame, in file units, as that
reader understands the file. three.js comes from the npm registry: installed once into
``$BONEFIT_THREE_DIR`` (default ``<tmp>/bonefit-test-three-<version>``); where Node or npm is
missing, or the install fails, the tests skip with the reason, except under
``BONEFIT_TEST_REQUIRE_SERVICES=1`` (CI), where they fail.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from numpy.typing import NDArray

THREE_VERSION = "0.187.0"

SCRIPT = """\
import { readFileSync } from 'node:fs';
import { Vector3 } from 'three';
import { BVHLoader } from 'three/examples/jsm/loaders/BVHLoader.js';

const { skeleton, clip } = new BVHLoader().parse(readFileSync(process.argv[2], 'utf8'));
const bones = skeleton.bones;
const tracks = new Map(clip.tracks.map((t) => [t.name, t]));
const frames = tracks.get(bones[0].name + '.quaternion').times.length;
const out = { names: bones.map((b) => b.name), positions: [] };
const v = new Vector3();
for (let i = 0; i < frames; i++) {
  for (const b of bones) {
    const p = tracks.get(b.name + '.position');
    if (p) b.position.fromArray(p.values, 3 * i);
    const q = tracks.get(b.name + '.quaternion');
    if (q) b.quaternion.fromArray(q.values, 4 * i);
  }
  bones[0].updateMatrixWorld(true);
  out.positions.push(bones.map((b) => b.getWorldPosition(v).toArray()));
}
process.stdout.write(JSON.stringify(out));
"""


def required() -> bool:
    """Whether CI demands every reader (fail instead of skip)."""
    return os.environ.get("BONEFIT_TEST_REQUIRE_SERVICES") == "1"


def unavailable(reason: str) -> None:
    """Skip, or fail where every reader is required."""
    if required():
        pytest.fail(f"{reason} (BONEFIT_TEST_REQUIRE_SERVICES=1)")
    pytest.skip(reason)


def install_three() -> Path:
    """The Node script reading a BVH with three.js (installing three.js once)."""
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        unavailable("three.js's BVHLoader needs node and npm on PATH")
    home = Path(os.environ.get("BONEFIT_THREE_DIR")
                or Path(tempfile.gettempdir()) / f"bonefit-test-three-{THREE_VERSION}")
    if not (home / "node_modules" / "three" / "package.json").exists():
        # install beside the target and rename, so parallel test runs never see half a tree
        staging = Path(tempfile.mkdtemp(prefix="bonefit-three-"))
        run = subprocess.run([str(npm), "install", "--prefix", str(staging), "--no-audit",
                              "--no-fund", f"three@{THREE_VERSION}"],
                             capture_output=True, text=True, timeout=600, check=False)
        if run.returncode != 0:
            shutil.rmtree(staging, ignore_errors=True)
            unavailable(f"npm install three@{THREE_VERSION} failed: {run.stderr[-500:]}")
        try:
            staging.rename(home)
        except OSError:  # another run installed it meanwhile
            shutil.rmtree(staging, ignore_errors=True)
    script = home / "bvh_positions.mjs"
    if not script.exists() or script.read_text() != SCRIPT:
        tmp = home / f"bvh_positions.{os.getpid()}.mjs"
        tmp.write_text(SCRIPT)
        tmp.replace(script)
    return script


def threejs_positions(script: Path, bvh: Path) -> dict[str, NDArray[np.float64]]:
    """World positions (F, 3) per joint as three.js's BVHLoader animates them."""
    node = shutil.which("node")
    assert node is not None
    run = subprocess.run([node, str(script), str(bvh)], capture_output=True, text=True,
                         timeout=300, check=False)
    assert run.returncode == 0, run.stderr
    data = json.loads(run.stdout)
    positions = np.asarray(data["positions"], dtype=float)  # (F, bones, 3)
    return {name: positions[:, k] for k, name in enumerate(data["names"])
            if name != "ENDSITE"}


def bvhio_positions(bvh: Path) -> dict[str, NDArray[np.float64]]:
    """World positions (F, 3) per joint as bvhio reads them."""
    with warnings.catch_warnings():  # bvhio imports PyGLM as "glm", which PyGLM deprecates
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import bvhio

    root = bvhio.readAsHierarchy(str(bvh))
    layout = root.layout()
    n_frames = len(root.Keyframes)
    out = {joint.Name: np.empty((n_frames, 3)) for joint, _, _ in layout}
    for frame in range(n_frames):
        root.loadPose(frame)
        for joint, _, _ in layout:
            p = joint.PositionWorld
            out[joint.Name][frame] = (p.x, p.y, p.z)
    return out
