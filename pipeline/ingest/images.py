"""The files a reader opens through a source (a glTF's buffers and images, an OBJ's
material library and its images, a COLLADA file's images, a .blend's external or packed
images): where they may come from, how large an image may be, and which were opened.

Where: inside the asset's folder (the source's folder: asset.toml names a file beside
itself), resolved after symbolic links; never an absolute path, a URL or a path that
leaves the folder. A relative path is taken as written against the file's folder; one
whose leading `../` would leave the folder is looked up with those steps dropped (the
Gazebo and SketchUp model layout `meshes/x.dae` + `materials/textures/y.png`, with the
mesh moved up beside asset.toml), and a bare name also in `textures/` and
`materials/textures/`.

How large: MAX_IMAGE_PIXELS and MAX_IMAGE_BYTES, from every route in. 8192 x 8192 is
the largest texture every current GPU and WebGL implementation samples (16384 is not
universal), and it decodes to 256 MB of RGBA; an image is held decoded once and encoded
once while read, so the cap bounds a reader's memory to about a gigabyte per image.
64 MB of encoded bytes is far above what a real 8K texture takes (a JPEG of 8192 x 8192
is 10-30 MB, a PNG of a painted texture 30-60 MB) and bounds what each image costs the
package, the scene and the tiles, which store it once each. The size is read from the
image's header (PIL opens lazily), so an image over the cap is never decoded.

Which: `SourceFiles.opened` maps each file read to the sha256 of the bytes read, named
relative to the asset's folder: the source task records them, and an edit of any of
them rebuilds the asset (engine.graph, Task.reads).
"""

from __future__ import annotations

import hashlib
import io
import re
from pathlib import Path
from urllib.parse import unquote

MAX_IMAGE_PIXELS = 8192 * 8192
MAX_IMAGE_BYTES = 64 << 20
MAX_FILE_BYTES = 512 << 20  # any other file a source names (a glTF buffer, a material library)
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")  # file:, http:, C: ...


def size_text(nbytes: int) -> str:
    return f"{nbytes / 2**20:.0f} MB" if nbytes >= 2**20 else f"{nbytes:,} bytes"


def image_problem(data: bytes) -> str | None:
    """Why the encoded image `data` is refused (over a cap, or not an image PIL reads),
    None when it fits. Only the header is read."""
    if len(data) > MAX_IMAGE_BYTES:
        return f"{size_text(len(data))}, over the {size_text(MAX_IMAGE_BYTES)} limit for an image"
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as image:
            width, height = image.size
    except Image.DecompressionBombError as e:  # PIL's own limit, above ours
        pixels = re.search(r"\((\d+) pixels\)", str(e))
        size = f"{int(pixels.group(1)):,} pixels" if pixels else "too many pixels"
        return f"a decompression bomb ({size}), over the {MAX_IMAGE_PIXELS:,} pixel limit for an image"
    except Exception as e:  # noqa: BLE001 - PIL raises many types on a damaged header
        return f"not an image this reader decodes ({type(e).__name__})"
    if width * height > MAX_IMAGE_PIXELS:
        return f"{width} x {height} pixels, over the {MAX_IMAGE_PIXELS:,} pixel limit (8192 x 8192) for an image"
    return None


def digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def is_image_name(name: str) -> bool:
    return Path(name.split("?")[0]).suffix.lower() not in (".bin", ".mtl", ".gltf", ".glb", ".dae", ".obj")


class Refused(OSError):
    """A file a source names that the reader does not open (the message says why)."""


class SourceFiles:
    """What trimesh's readers open through a source file (a trimesh resolver:
    `get`, `[name]`, `keys`, `namespaced`, `write`), limited to the asset's folder.

    served: bytes under a name of the reader's own (a glTF's buffers and embedded
    images, already read and checked), served before any file.
    opened: path relative to the folder -> sha256 of the bytes read (None: looked
    for there and not found, so that adding it rebuilds the asset too).
    problems: name as asked -> why it was not served (not found, refused, too large)."""

    def __init__(self, source: Path, served: dict[str, bytes] | None = None):
        self.source = Path(source)
        self.root = self.source.resolve().parent
        self.served = dict(served or {})
        self.opened: dict[str, str | None] = {}
        self.problems: dict[str, str] = {}

    # --- the resolver interface trimesh calls ----------------------------------------
    def get(self, name: str) -> bytes:
        name = str(name)
        try:
            if name in self.served:
                data = self.served[name]
            else:
                data = self.read(name, image=is_image_name(name))
                return data
            if is_image_name(name) and (why := image_problem(data)):
                raise Refused(why)
            return data
        except OSError as e:
            self.problems.setdefault(name, str(e))
            raise

    __getitem__ = get

    def keys(self):
        return []

    def namespaced(self, namespace: str) -> "SourceFiles":
        return self

    def write(self, name: str, data) -> None:
        raise PermissionError("reading a source writes nothing")

    # --- the folder ----------------------------------------------------------------------
    def locate(self, name: str) -> Path:
        """The file `name` (as written in the source) names inside the folder; Refused
        for an absolute path, a URL or a path out of it, FileNotFoundError when absent."""
        written = unquote(name.strip())
        if "\0" in written:
            raise Refused("a path with a NUL character (refused)")
        if not written or _SCHEME.match(written) or written.startswith(("/", "\\")):
            raise Refused("an absolute path or URL (refused: only files in the asset's folder are read)")
        parts = Path(written.replace("\\", "/")).parts
        candidates = [Path(*parts)]
        leading = next((i for i, p in enumerate(parts) if p != ".."), len(parts))
        if leading and leading < len(parts):  # ../materials/textures/x.png: the mesh left meshes/
            candidates.append(Path(*parts[leading:]))
        if len(parts) == 1:
            candidates += [Path("textures") / parts[0], Path("materials") / "textures" / parts[0]]
        for rel in candidates:
            target = (self.root / rel).resolve()  # through `..` and symbolic links
            if target.is_relative_to(self.root) and target.is_file():
                return target
        if not (self.root / candidates[0]).resolve().is_relative_to(self.root):
            raise Refused("leaves the asset's folder (refused)")
        for rel in candidates:  # where it was looked for: a file that appears there rebuilds the asset
            target = (self.root / rel).resolve()
            if target.is_relative_to(self.root):
                self.opened.setdefault(target.relative_to(self.root).as_posix(), None)
        raise FileNotFoundError(f"not found in the asset's folder {self.root.name}/")

    def read(self, name: str, image: bool = False) -> bytes:
        """The bytes of the file `name` names (capped before reading), recorded as opened."""
        path = self.locate(name)
        limit = MAX_IMAGE_BYTES if image else MAX_FILE_BYTES
        size = path.stat().st_size
        if size > limit:
            raise Refused(f"{size_text(size)}, over the {size_text(limit)} limit" + (" for an image" if image else ""))
        data = path.read_bytes()
        self.record(path, data)
        if image and (why := image_problem(data)):
            raise Refused(why)
        return data

    def record(self, path: Path, data: bytes) -> None:
        """`path` (inside the folder) was read as `data`."""
        self.opened[Path(path).resolve().relative_to(self.root).as_posix()] = digest(data)
