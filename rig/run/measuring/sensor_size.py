"""Image mode's sensor size on a real camera: learnt from the first whole frame it delivers, then checked.

Tiles lie on a grid fixed to the sensor and their directions come from the camera model of the whole sensor,
so image mode needs the sensor's (width, height) in pixels. A simulated camera's is ``[camera] resolution``;
a real camera's is not a rig file key (a tethered camera, a GenICam one, a webcam each deliver what their
sensor is), so the run takes one frame before its first point and reads the size off it. Where something
else states the size the camera model assumes (a geometry calibration, fitted on whole frames of this
camera), the two must agree: a calibration from another camera or another crop would place every tile's
directions wrongly, so the run refuses to start and names both sizes. A frame that is a crop (an origin
other than the sensor's corner) cannot say the sensor's size and is refused too, and so is an odd ``tile_px``
when that frame is a raw mosaic (a tile must hold whole 2x2 colour cells): both before anything moves.

A resumed run learns the size again and checks it against the one its journal's image points were measured
with (their ``sensor_px``): a tile's number names other pixels on another sensor.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

from acquisition.frame import Camera, Frame
from rig.run.measuring.image_capture import ImageModeError
from rig.run.measuring.measure import CaptureSettings


def whole_frame(camera: Camera, exposure_s: float) -> Frame:
    """One frame the camera delivers at ``exposure_s`` seconds, refused unless it is the whole sensor's."""
    camera.set_exposure(exposure_s)
    frame = camera.capture()
    h, w = frame.data.shape[:2]
    if tuple(frame.origin_xy) != (0, 0):
        raise ImageModeError(
            f"{camera.identity}: image mode learns the sensor's size from a whole frame, but the camera delivered "
            f"a {w} x {h} px crop at {tuple(frame.origin_xy)}: set the camera (or its tethering program) to "
            "deliver whole frames"
        )
    return frame


def check_sensor(found: tuple[int, int], found_from: str, expected: tuple[int, int] | None,
                 expected_from: str) -> None:  # fmt: skip
    """Refuse a sensor of ``found`` (width, height) px where ``expected`` states another; both sources named."""
    if expected is None or tuple(found) == tuple(expected):
        return
    raise ImageModeError(
        f"{found_from}: {found[0]} x {found[1]} px, but {expected_from} says {expected[0]} x {expected[1]} px: "
        "image mode's tiles and their directions need the camera model of the sensor that delivers the frames "
        "(calibrate the geometry again with this camera, or deliver its whole frames)"
    )


def journal_sensor(records: Sequence[dict[str, Any]]) -> tuple[int, int] | None:
    """The sensor (width, height) in pixels the journal's image points were measured with, None if none."""
    for record in records:
        size = record.get("sensor_px") if record.get("kind") == "point" else None
        if isinstance(size, list) and len(size) == 2:
            return int(size[0]), int(size[1])
    return None


def learn_sensor(camera: Camera, capture: CaptureSettings, records: Sequence[dict[str, Any]] = ()) -> CaptureSettings:
    """``capture`` with image mode's sensor size known: as given, or learnt from one frame (see module docstring).

    ``records``: the run's journal so far; a resumed run's sensor must be the one its points were measured on.
    """
    image = capture.image
    if image is None:
        return capture
    earlier = journal_sensor(records)
    if image.resolution is not None:
        check_sensor(image.resolution, "the camera's sensor", image.expected_sensor, image.expected_from)
        check_sensor(image.resolution, "the camera's sensor", earlier, "the run's journal")
        return capture
    exposure = min(max(capture.first_exposure_s, capture.timing.min_exposure_s), capture.timing.max_exposure_s)
    frame = whole_frame(camera, exposure)
    size = (int(frame.data.shape[1]), int(frame.data.shape[0]))
    if size[0] < image.tile_px or size[1] < image.tile_px:
        raise ImageModeError(f"{camera.identity}: a {size[0]} x {size[1]} px frame holds no {image.tile_px} px tile")
    if frame.kind == "raw" and image.tile_px % 2:  # refused before anything moves, not at the first point
        raise ImageModeError(f"{camera.identity}: tile_px = {image.tile_px} on a raw (mosaic) camera: expected an even "
                             "tile_px, so a tile holds whole 2x2 colour cells")  # fmt: skip
    where = f"{camera.identity}: the whole frame the camera delivered"
    check_sensor(size, where, image.expected_sensor, image.expected_from)
    check_sensor(size, where, earlier, "the run's journal (its image points were measured on that sensor)")
    return dataclasses.replace(capture, image=dataclasses.replace(image, resolution=size))
