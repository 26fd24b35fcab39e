"""glTF 2.0 binary (``.glb``) files, written and read with ``json`` + ``struct`` only.

A GLB file is a 12-byte header (magic ``glTF``, version 2, total length) followed by
chunks of (length, type, data): one JSON chunk (padded with spaces to a multiple of 4
bytes) and one BIN chunk (padded with zeros). Every length and offset is a multiple of
4 (glTF 2.0 specification, section "Binary glTF Layout").

``textured_plane`` builds the one scene the exports need: a flat rectangle in the XY
plane facing +Z (the default view direction of glTF viewers), long side 1 m, with one
material. UVs follow glTF's convention: (0, 0) is the image's top-left corner, u to the
right, v down. The tangent is +X (increasing u) with w = +1, so the bitangent
``cross(normal, tangent) * w`` is +Y, towards the image's top: the OpenGL / green-up
normal-map convention glTF requires, and the one of our maps (SPEC section 2).
"""

from __future__ import annotations

import json
import os
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from materials.io.atomic import atomic_file
from materials.io.errors import FormatError

__all__ = ["GlbFile", "pack_glb", "write_glb", "read_glb", "textured_plane", "GLB_MAGIC", "SPECULAR_EXTENSION"]

GLB_MAGIC = b"glTF"
GLB_VERSION = 2
CHUNK_JSON = 0x4E4F534A  # "JSON" little-endian
CHUNK_BIN = 0x004E4942  # "BIN\0" little-endian
SPECULAR_EXTENSION = "KHR_materials_specular"

# glTF enums (specification, "accessor.componentType", "bufferView.target", "sampler").
_FLOAT, _UNSIGNED_SHORT = 5126, 5123
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
_LINEAR, _LINEAR_MIPMAP_LINEAR, _CLAMP_TO_EDGE = 9729, 9987, 33071
_COMPONENTS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_DTYPES: dict[int, np.dtype] = {_FLOAT: np.dtype("<f4"), _UNSIGNED_SHORT: np.dtype("<u2")}


def _pad4(data: bytes, fill: bytes) -> bytes:
    return data + fill * (-len(data) % 4)


@dataclass(frozen=True)
class GlbFile:
    """A parsed GLB: the glTF JSON and the binary buffer (``buffers[0]``)."""

    gltf: dict
    binary: bytes

    def buffer_view(self, index: int) -> bytes:
        view = self.gltf["bufferViews"][index]
        start = view.get("byteOffset", 0)
        return self.binary[start : start + view["byteLength"]]

    def image_bytes(self, index: int) -> bytes:
        """The encoded bytes (PNG) of ``images[index]``."""
        return self.buffer_view(self.gltf["images"][index]["bufferView"])

    def accessor(self, index: int) -> np.ndarray:
        """``accessors[index]`` as ``[count, components]`` (tightly packed views only)."""
        acc = self.gltf["accessors"][index]
        view = self.gltf["bufferViews"][acc["bufferView"]]
        if "byteStride" in view:
            raise FormatError("<glb>", "interleaved buffer views are not read here")
        dtype = _DTYPES[acc["componentType"]]
        n = _COMPONENTS[acc["type"]]
        start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
        flat = np.frombuffer(self.binary, dtype=dtype, count=acc["count"] * n, offset=start)
        return flat.reshape(acc["count"], n)

    def texture_image(self, texture_info: dict) -> bytes:
        """Encoded image of a material's ``{"index": i}`` texture reference."""
        return self.image_bytes(self.gltf["textures"][texture_info["index"]]["source"])


def pack_glb(gltf: dict, binary: bytes) -> bytes:
    """GLB bytes of a glTF JSON whose ``buffers[0]`` is ``binary`` (no ``uri``)."""
    body = _pad4(json.dumps(gltf, separators=(",", ":")).encode("utf-8"), b" ")
    chunks = struct.pack("<II", len(body), CHUNK_JSON) + body
    if binary:
        data = _pad4(binary, b"\x00")
        chunks += struct.pack("<II", len(data), CHUNK_BIN) + data
    return struct.pack("<4sII", GLB_MAGIC, GLB_VERSION, 12 + len(chunks)) + chunks


def write_glb(path: str | os.PathLike, gltf: dict, binary: bytes) -> Path:
    """Write :func:`pack_glb` bytes to ``path``, atomically."""
    path = Path(path)
    data = pack_glb(gltf, binary)
    with atomic_file(path) as tmp:
        tmp.write_bytes(data)
    return path


def read_glb(path: str | os.PathLike) -> GlbFile:
    """Read and check a GLB file: header, chunk layout and 4-byte alignment.

    Raises:
        FormatError: naming ``path``: not a GLB, wrong version, lengths that do not add
            up, chunks out of order or not 4-byte aligned, invalid JSON.
    """
    path = Path(path)
    if not path.is_file():
        raise FormatError(path, "GLB file does not exist")
    data = path.read_bytes()
    if len(data) < 20:
        raise FormatError(path, f"too short for a GLB file ({len(data)} bytes)")
    magic, version, length = struct.unpack_from("<4sII", data, 0)
    if magic != GLB_MAGIC:
        raise FormatError(path, "not a GLB file (no 'glTF' magic)")
    if version != GLB_VERSION:
        raise FormatError(path, f"GLB version {version}; expected {GLB_VERSION}")
    if length != len(data):
        raise FormatError(path, f"header says {length} bytes, the file has {len(data)}")
    chunks, offset = [], 12
    while offset < length:
        if offset + 8 > length:
            raise FormatError(path, f"truncated chunk header at byte {offset}")
        size, kind = struct.unpack_from("<II", data, offset)
        if size % 4 or offset % 4:
            raise FormatError(path, f"chunk at byte {offset} ({size} bytes) is not 4-byte aligned")
        if offset + 8 + size > length:
            raise FormatError(path, f"chunk at byte {offset} runs past the end of the file")
        chunks.append((kind, data[offset + 8 : offset + 8 + size]))
        offset += 8 + size
    if not chunks or chunks[0][0] != CHUNK_JSON:
        raise FormatError(path, "the first chunk must be JSON")
    if len(chunks) > 1 and chunks[1][0] != CHUNK_BIN:
        raise FormatError(path, "the second chunk must be BIN")
    try:
        gltf = json.loads(chunks[0][1].decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise FormatError(path, f"JSON chunk is not valid JSON: {err}") from err
    binary = chunks[1][1] if len(chunks) > 1 else b""
    buffers = gltf.get("buffers", [])
    if buffers and buffers[0].get("byteLength", 0) > len(binary):
        raise FormatError(path, f"buffers[0] claims {buffers[0]['byteLength']} bytes, BIN chunk has {len(binary)}")
    return GlbFile(gltf, binary)


class _BinaryBuilder:
    """Appends 4-byte-aligned buffer views and accessors to a glTF JSON."""

    def __init__(self, gltf: dict) -> None:
        self.gltf = gltf
        self.data = bytearray()

    def view(self, payload: bytes, target: int | None = None) -> int:
        self.data.extend(b"\x00" * (-len(self.data) % 4))
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(payload)}
        if target is not None:
            view["target"] = target
        self.data.extend(payload)
        self.gltf["bufferViews"].append(view)
        return len(self.gltf["bufferViews"]) - 1

    def accessor(self, array: np.ndarray, kind: str, target: int) -> int:
        array = np.ascontiguousarray(array)
        component = _FLOAT if array.dtype == np.float32 else _UNSIGNED_SHORT
        values = array.reshape(array.shape[0], -1)
        acc = {
            "bufferView": self.view(array.astype(_DTYPES[component]).tobytes(), target),
            "componentType": component,
            "count": int(values.shape[0]),
            "type": kind,
            # min/max: required for POSITION, allowed (and checked by the tests) for all.
            "min": [v.item() for v in values.min(axis=0)],
            "max": [v.item() for v in values.max(axis=0)],
        }
        self.gltf["accessors"].append(acc)
        return len(self.gltf["accessors"]) - 1


def textured_plane(
    textures: dict[str, bytes],
    *,
    aspect: float = 1.0,
    name: str = "material",
    specular_color_factor: float | None = None,
    generator: str = "dgrsise",
) -> tuple[dict, bytes]:
    """glTF JSON and binary buffer of one textured plane (module docstring).

    Args:
        textures: PNG bytes by slot: ``"baseColor"`` (sRGB), ``"metallicRoughness"``
            (linear; G roughness, B metallic), ``"normal"`` (linear (n+1)/2, OpenGL),
            and optionally ``"specularColor"`` (sRGB; adds ``KHR_materials_specular``).
        aspect: width / height of the maps; the long side of the plane is 1 m.
        name: the material's and the mesh's name.
        specular_color_factor: ``specularColorFactor`` (one value for R, G, B) of the
            extension; needed with a ``"specularColor"`` texture.

    Returns:
        ``(gltf, binary)`` for :func:`write_glb` / :func:`pack_glb`.
    """
    missing = {"baseColor", "metallicRoughness", "normal"} - set(textures)
    if missing:
        raise ValueError(f"textures missing: {sorted(missing)}")
    if not aspect > 0:
        raise ValueError(f"aspect must be positive, got {aspect}")
    w, h = (1.0, 1.0 / aspect) if aspect >= 1 else (aspect, 1.0)
    gltf: dict = {
        "asset": {"version": "2.0", "generator": generator},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": name}],
        "buffers": [],
        "bufferViews": [],
        "accessors": [],
    }
    b = _BinaryBuilder(gltf)
    # Corners: top-left, top-right, bottom-right, bottom-left (UV (0, 0) = image top-left).
    positions = np.array([[-w / 2, h / 2, 0], [w / 2, h / 2, 0], [w / 2, -h / 2, 0], [-w / 2, -h / 2, 0]], np.float32)
    normals = np.tile(np.array([0, 0, 1], np.float32), (4, 1))
    tangents = np.tile(np.array([1, 0, 0, 1], np.float32), (4, 1))
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    indices = np.array([3, 2, 1, 3, 1, 0], np.uint16)  # counter-clockwise seen from +Z
    attributes = {
        "POSITION": b.accessor(positions, "VEC3", _ARRAY_BUFFER),
        "NORMAL": b.accessor(normals, "VEC3", _ARRAY_BUFFER),
        "TANGENT": b.accessor(tangents, "VEC4", _ARRAY_BUFFER),
        "TEXCOORD_0": b.accessor(uvs, "VEC2", _ARRAY_BUFFER),
    }
    index_accessor = b.accessor(indices[:, None], "SCALAR", _ELEMENT_ARRAY_BUFFER)
    gltf["meshes"] = [
        {"name": name, "primitives": [{"attributes": attributes, "indices": index_accessor, "material": 0}]}
    ]
    gltf["samplers"] = [
        {"magFilter": _LINEAR, "minFilter": _LINEAR_MIPMAP_LINEAR, "wrapS": _CLAMP_TO_EDGE, "wrapT": _CLAMP_TO_EDGE}
    ]
    gltf["images"], gltf["textures"] = [], []
    slot_index = {}
    for slot in ("baseColor", "metallicRoughness", "normal", "specularColor"):
        if slot in textures:
            gltf["images"].append({"name": slot, "mimeType": "image/png", "bufferView": b.view(textures[slot])})
            gltf["textures"].append({"sampler": 0, "source": len(gltf["images"]) - 1})
            slot_index[slot] = len(gltf["textures"]) - 1
    material: dict = {
        "name": name,
        "pbrMetallicRoughness": {
            "baseColorFactor": [1.0, 1.0, 1.0, 1.0],
            "baseColorTexture": {"index": slot_index["baseColor"]},
            "metallicFactor": 1.0,
            "roughnessFactor": 1.0,
            "metallicRoughnessTexture": {"index": slot_index["metallicRoughness"]},
        },
        "normalTexture": {"index": slot_index["normal"], "scale": 1.0},
    }
    if "specularColor" in textures:
        if specular_color_factor is None:
            raise ValueError("a specularColor texture needs specular_color_factor")
        material["extensions"] = {
            SPECULAR_EXTENSION: {
                "specularFactor": 1.0,
                "specularColorFactor": [float(specular_color_factor)] * 3,
                "specularColorTexture": {"index": slot_index["specularColor"]},
            }
        }
        gltf["extensionsUsed"] = [SPECULAR_EXTENSION]
    gltf["materials"] = [material]
    binary = bytes(b.data)
    gltf["buffers"] = [{"byteLength": len(binary)}]
    return gltf, binary
