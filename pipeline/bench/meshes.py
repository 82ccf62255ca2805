"""Hard test meshes for the simplifiers: a CAD-like post insulator of thin sheds, a
noisy sphere, a strip of needle triangles. Each returns (vertices (n, 3) float64,
faces (m, 3) int64)."""

from __future__ import annotations

import numpy as np


def insulator_mesh(sheds: int = 40, segments: int = 160, target_faces: int = 200_000) -> tuple[np.ndarray, np.ndarray]:
    """A CAD-like post insulator: a long thin core (radius 4 cm, 2 m) carrying `sheds`
    thin sheds (2 mm thick, 12 cm overhang), as one closed surface of revolution of
    about target_faces triangles."""
    z, r = [0.0], [0.04]
    pitch = 2.0 / sheds
    for k in range(sheds):
        z0 = k * pitch + 0.3 * pitch
        z += [z0, z0 + 0.004, z0 + 0.006, z0 + 0.002 + 0.3 * pitch * 0.1]
        r += [0.04, 0.16, 0.16, 0.04]
    z += [2.0]
    r += [0.04]
    profile = np.stack([r, z], axis=1)
    # subdivide the profile so the face count lands near the target
    rings = max(2, target_faces // (2 * segments))
    t = np.linspace(0, 1, len(profile))
    ti = np.linspace(0, 1, max(rings, len(profile)))
    ti = np.unique(np.r_[t, ti])
    prof = np.stack([np.interp(ti, t, profile[:, 0]), np.interp(ti, t, profile[:, 1])], axis=1)
    return revolve(prof, segments)


def revolve(profile: np.ndarray, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Closed surface of revolution about Z of a (k, 2) (radius, z) profile, capped."""
    k = len(profile)
    a = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ring = np.stack([np.cos(a), np.sin(a)], axis=1)
    v = np.concatenate([
        np.column_stack([profile[i, 0] * ring, np.full(segments, profile[i, 1])]) for i in range(k)
    ] + [np.array([[0, 0, profile[0, 1]], [0, 0, profile[-1, 1]]])])
    i = np.arange(k - 1)[:, None] * segments
    j = np.arange(segments)[None, :]
    a0, a1 = i + j, i + (j + 1) % segments
    b0, b1 = a0 + segments, a1 + segments
    side = np.concatenate([np.stack([a0, a1, b1], -1).reshape(-1, 3), np.stack([a0, b1, b0], -1).reshape(-1, 3)])
    bottom, top = k * segments, k * segments + 1
    jj = np.arange(segments)
    cap0 = np.stack([np.full(segments, bottom), (jj + 1) % segments, jj], axis=1)
    cap1 = np.stack([np.full(segments, top), (k - 1) * segments + jj, (k - 1) * segments + (jj + 1) % segments], axis=1)
    return v, np.concatenate([side, cap0, cap1]).astype(np.int64)


def noisy_sphere(subdivisions: int = 6, noise: float = 0.002, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere (20 * 4^s faces) with radial noise of `noise` m (std)."""
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions)
    rng = np.random.default_rng(seed)
    v = s.vertices * (1.0 + noise * rng.standard_normal(len(s.vertices)))[:, None]
    return v, np.asarray(s.faces, dtype=np.int64)


def sliver_mesh(n: int = 200, length: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A long thin open strip of needle triangles (aspect ratio ~ 1000) on a gentle
    wave: n x 2 vertices, 2 (n - 1) faces."""
    x = np.linspace(0, length, n)
    y = np.array([0.0, length / 1000.0])
    xx, yy = np.meshgrid(x, y, indexing="ij")
    zz = 0.01 * np.sin(6 * xx)
    v = np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=1)
    i = np.arange(n - 1) * 2
    f = np.concatenate([np.stack([i, i + 2, i + 1], 1), np.stack([i + 1, i + 2, i + 3], 1)])
    return v, f.astype(np.int64)
