"""Gazebo out: the twin's sun, moving parts and materials pushed into a running gz-sim.

Through gz-sim's own transport interfaces, by tools/gzbridge (C++, Debian's
ignition-transport11 and ignition-msgs8), which takes one command per line:
- the sun: the world's `light_config` service (ignition.msgs.Light), as gz-sim's
  UserCommands system offers it (Fortress and Harmonic);
- moving parts: joint position commands (ignition.msgs.Double) on the topic the
  world's JointPositionController of that joint listens on (export.names.
  joint_command_topic, which the world's writer gives the controller: scene.world_joints),
  or `set_pose`;
- materials: `visual_config` (ignition.msgs.Visual), which Harmonic offers and
  Fortress does not (its failure is counted, not fatal).
A command that fails is counted and its first error of each kind is logged; the twin
never waits longer than the bridge's timeout for gz-sim.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import threading
from collections import Counter
from pathlib import Path

import numpy as np

from ..export.names import joint_command_topic
from ..geometry.transform import quaternions_from_matrices

log = logging.getLogger("twin.gazebo")
BRIDGE = Path(__file__).resolve().parents[2] / "tools" / "gzbridge" / "gzbridge"
INSTALL_HINT = "bash .ci/install-tools (builds tools/gzbridge against Debian's ignition-transport11)"


def _n(v: float) -> str:
    return repr(float(v))  # shortest text that reads back to the same double


class GazeboBridge:
    def __init__(self, world: str, timeout_ms: int = 500, bridge: Path = BRIDGE, env: dict | None = None):
        if not Path(bridge).is_file():
            raise FileNotFoundError(f"{bridge} is not built: {INSTALL_HINT}")
        self.world = world
        self.sent = Counter()
        self.failed = Counter()
        self._errors: set[str] = set()
        self._lock = threading.Lock()
        self._process = subprocess.Popen([str(bridge), "send", "--world", world, "--timeout", str(timeout_ms)],
                                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1,
                                         env={**os.environ, **(env or {})})
        self._reader = threading.Thread(target=self._read_replies, name="gzbridge replies", daemon=True)
        self._reader.start()

    # --- what the twin pushes ---------------------------------------------------

    def sun(self, travel_enu, intensity: float, colour=(1.0, 1.0, 1.0), name: str = "sun") -> None:
        """The directional light `name`: direction of travel (ENU, towards the ground),
        intensity and diffuse colour, as the world's <light> has them."""
        d = np.asarray(travel_enu, dtype=np.float64)
        self._send("light", name, *(_n(c) for c in d), _n(intensity), *(_n(c) for c in colour))

    def joint(self, tag: str, joint: str, position: float) -> None:
        """Placement `tag`'s joint `joint` (its name in the asset) to `position`."""
        self._send("joint", joint_command_topic(tag, joint), _n(position))

    def pose(self, name: str, matrix) -> None:
        m = np.asarray(matrix, dtype=np.float64)
        w, x, y, z = quaternions_from_matrices(m[None, :3, :3])[0]
        self._send("pose", name, *(_n(c) for c in m[:3, 3]), _n(x), _n(y), _n(z), _n(w))

    def visual(self, name: str, rgba) -> None:
        self._send("visual", name, *(_n(c) for c in rgba))

    def close(self) -> None:
        if self._process.poll() is None:
            self._process.stdin.close()
            try:
                self._process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        self._reader.join(timeout=5)

    def __enter__(self) -> "GazeboBridge":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- the line protocol ------------------------------------------------------

    def _send(self, cmd: str, *fields: str) -> None:
        if any(" " in f or "\n" in f or not f for f in fields):
            raise ValueError(f"gzbridge {cmd}: a name holds no space or newline: {fields}")
        with self._lock:
            self.sent[cmd] += 1
            try:
                self._process.stdin.write(" ".join((cmd, *fields)) + "\n")
                self._process.stdin.flush()
            except BrokenPipeError:
                self._fail(cmd, "the bridge process ended")

    def _read_replies(self) -> None:
        for line in self._process.stdout:
            try:
                reply = json.loads(line)
            except json.JSONDecodeError:
                continue
            if not reply.get("ok"):
                self._fail(reply.get("cmd", "?"), reply.get("error", "failed"))

    def _fail(self, cmd: str, error: str) -> None:
        self.failed[cmd] += 1
        if (cmd, error) not in self._errors:
            self._errors.add((cmd, error))
            log.warning("gazebo %s: %s (counted; not logged again)", cmd, error)
