"""Camera bookmarks: a view saved to a small JSON file and restored later.

Why a file: a view found in the viewer (key ``C``) can be rendered again at another size with
``clipvol render --camera FILE.json``, shared with a colleague, or put in a paper's methods. The
document holds the :class:`~clipvol.scene.camera.Camera` fields as they are (eye or centre, the
point looked at, up, field of view or orthographic extent, depth range, image size); restoring
may change the image size and keeps everything else.

::

    {"format": "clipvol-camera", "version": 1, "orthographic": false,
     "eye": [x, y, z], "target": [x, y, z], "up": [x, y, z], "fov_y": 35.0,
     "width": 1.0, "height": 1.0, "size": [960, 640], "near": 0.1, "far": 1000.0}

For an orthographic camera ``eye`` is the centre of the view and ``target`` a point along the
view direction; ``width``/``height`` are the world extent seen.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import ParameterError
from .camera import Camera

__all__ = ["CAMERA_FORMAT", "camera_to_json", "camera_from_json", "save_camera", "load_camera"]

CAMERA_FORMAT = "clipvol-camera"


def camera_to_json(cam: Camera) -> dict:
    """The JSON document of ``cam`` (see the module docstring)."""
    return {
        "format": CAMERA_FORMAT,
        "version": 1,
        "orthographic": bool(cam.ortho),
        "eye": [float(v) for v in cam.position],
        "target": [float(v) for v in cam.aim],
        "up": [float(v) for v in cam.up_hint],
        "fov_y": float(cam.fov_y),
        "width": float(cam.width),
        "height": float(cam.height),
        "size": [int(v) for v in cam.size],
        "near": float(cam.near),
        "far": float(cam.far),
    }


def camera_from_json(doc, size=None, where: str = "camera") -> Camera:
    """The :class:`Camera` of a document; ``size`` (``(w, h)``) replaces the saved image size."""
    if not isinstance(doc, dict) or doc.get("format") != CAMERA_FORMAT:
        raise ParameterError(f"{where}: expected a JSON object with format {CAMERA_FORMAT!r}")
    try:
        ortho = bool(doc["orthographic"])
        s = tuple(size) if size is not None else tuple(doc["size"])
        width, height = float(doc["width"]), float(doc["height"])
        if ortho and size is not None:  # keep the vertical extent, follow the new aspect
            width = height * s[0] / s[1]
        return Camera(ortho, tuple(doc["eye"]), tuple(doc["target"]), tuple(doc["up"]), float(doc["fov_y"]),
                      width, height, s, float(doc["near"]), float(doc["far"]))
    except (KeyError, TypeError, ValueError, ZeroDivisionError) as e:
        raise ParameterError(f"{where}: expected the fields of a saved camera, got {e!s}") from None
    except ParameterError as e:
        raise ParameterError(f"{where}: {e}") from None


def save_camera(cam: Camera, path) -> Path:
    """Write ``cam`` to ``path`` (its folder must exist); returns the path."""
    path = Path(path)
    if not path.parent.is_dir():
        raise ParameterError(f"{path}: expected an existing folder {str(path.parent)!r} to save the camera in")
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(camera_to_json(cam), indent=1) + "\n")
    tmp.replace(path)
    return path


def load_camera(path, size=None) -> Camera:
    """The camera saved in ``path``; ``size`` replaces its image size."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except FileNotFoundError:
        raise ParameterError(f"{path}: no such camera file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ParameterError(f"{path}: expected a JSON camera, could not read it ({e})") from None
    return camera_from_json(doc, size, str(path))
