"""The rig file's ``[camera]`` table: every key's type, bound and meaning, and which backend may set which.

What lives where: each key's type, bounds, default and meaning are here (one typed field of :class:`Camera`);
which backend reads a key, and which keys it needs, is the backend's record and nowhere else:
``CameraBackend.keys`` and ``required`` (``acquisition.cameras.builtin`` for gonio's own) for a registered
camera, ``BackendTraits.camera_keys`` for one that comes with a rig backend (the simulated rig's, in
``simulator.backend``). Adding a key to a backend is one edit there, plus its field here if the key is new.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import Field, field_validator, model_validator

from acquisition.cameras import CameraError
from acquisition.cameras import registry as cameras
from acquisition.cameras.trigger import check_callable, check_command
from rig.run import registry
from rig.run.config.strict import Levels, Seconds, Strict, one_of


class Noise(Strict):
    """``[camera.noise]``: the sensor's gain (e-/DN), noise (e-), dark current (e-/s) and levels (DN)."""

    # A gain of 1e-3 e-/DN to 1e5 e-/DN spans every sensor there is; beyond it the noise model's sums overflow.
    e_per_dn: Annotated[float, Field(ge=1e-3, le=1e5, allow_inf_nan=False)] = 4.0
    read_noise_e: Annotated[float, Field(ge=0, le=1e6, allow_inf_nan=False)] = 3.0
    dark_current_e_per_s: Annotated[float, Field(ge=0, le=1e9, allow_inf_nan=False)] = 0.5
    black_level_dn: Levels = 512.0
    white_level_dn: Annotated[float, Field(gt=0, le=2**32, allow_inf_nan=False)] = 16383.0
    full_well_e: Annotated[float, Field(gt=0, le=1e9, allow_inf_nan=False)] = 60000.0


#: [camera] keys every backend reads; the others belong to one backend or a few (``CameraBackend.keys``).
COMMON_CAMERA_KEYS = ("backend", "min_exposure_s", "max_exposure_s", "overhead_s", "roi", "noise", "calibration",
                      "flat_field", "capture_timeout_s")  # fmt: skip


class Camera(Strict):
    """``[camera]``: the camera backend, its exposure range (s), ROI (pixels), noise and calibration files.

    ``backend`` names a registered camera backend (``gonio.cameras``: folder, opencv, gphoto2, genicam, or a
    lab's own) or one that comes with the rig backend (the simulated rig's "simulated"). Besides the common
    keys each backend reads its own (this module's docstring says where that is written); a key of another
    backend is an error naming whose it is. ``calibration`` and ``flat_field`` are files written by
    ``gonio calibrate camera`` (relative to the rig file). A required key's ``description`` is what its error
    says it is.
    """

    backend: str = "simulated"
    min_exposure_s: Seconds = 1e-5
    max_exposure_s: Seconds = 30.0
    overhead_s: Annotated[float, Field(ge=0, le=3600, allow_inf_nan=False)] = 0.0
    #: Wall seconds a capture may take beyond twice its exposure before the run stops on a camera fault.
    capture_timeout_s: Annotated[float, Field(gt=0, le=3600)] = 60.0
    roi: tuple[int, int, int, int] | None = None
    noise: Noise = Noise()
    calibration: str | None = None
    flat_field: str | None = None
    resolution: tuple[Annotated[int, Field(ge=8, le=8192)], Annotated[int, Field(ge=8, le=8192)]] = (32, 32)
    spp: Annotated[int, Field(ge=1, le=4096)] = 4
    variant: str | None = None
    folder: Annotated[str | None, Field(description="the directory the tethering software writes to")] = None
    #: A command as a list of arguments with {exposure_s}-style placeholders, or "module:function".
    trigger: tuple[str, ...] | str | None = None
    trigger_timeout_s: Seconds | None = None
    pattern: tuple[str, ...] | None = None
    poll_interval_s: Annotated[float, Field(gt=0, le=60)] | None = None
    stable_polls: Annotated[int, Field(ge=1, le=100)] | None = None
    settle_s: Annotated[float, Field(ge=0, le=3600, allow_inf_nan=False)] | None = None
    accept_unconfirmed_exposure: bool | None = None
    #: An index, a device path, a video file or an image-sequence pattern.
    device: Annotated[int, Field(ge=0, le=65535)] | str | None = None
    api: Literal["any", "v4l2", "images", "ffmpeg", "gstreamer"] | None = None
    strict: bool | None = None
    #: Where libgphoto2 finds the camera: "usb:001,004", "disk:/path".
    port: str | None = None
    model: str | None = None
    download_dir: str | None = None
    keep_on_camera: bool | None = None
    cti_file: Annotated[str | None, Field(description="the GenTL producer (.cti file) of the camera's vendor")] = None
    serial_number: str | None = None
    index: Annotated[int, Field(ge=0, le=65535)] | None = None
    pixel_format: str | None = None
    timeout_s: Annotated[float, Field(gt=0, le=3600)] | None = None
    discard_frames: Annotated[int, Field(ge=0, le=64)] | None = None
    options: dict[str, Any] | None = None

    @field_validator("backend")
    @classmethod
    def _registered(cls, value: str) -> str:
        return one_of(value, registry.provided_cameras() + cameras.names())

    @field_validator("trigger")
    @classmethod
    def _trigger(cls, value: tuple[str, ...] | str | None) -> tuple[str, ...] | str | None:
        if isinstance(value, str):
            check_callable(value)
        elif value is not None:
            check_command(value)
        return value

    @model_validator(mode="after")
    def _consistent(self) -> Camera:
        if self.min_exposure_s >= self.max_exposure_s:
            raise ValueError(f"min_exposure_s {self.min_exposure_s!r} must be below max_exposure_s")
        keys, required = _backend_keys(self.backend)
        stray = sorted(set(self.model_fields_set) - set(COMMON_CAMERA_KEYS) - set(keys))
        if stray:
            whose = _owners(stray[0])
            raise ValueError(
                f"camera.{stray[0]} = {_shown(getattr(self, stray[0]))}: the {self.backend!r} camera backend does "
                f"not read this key{f' ({whose})' if whose else ''}; it reads "
                f"{', '.join(keys) or 'only the common keys'} besides {', '.join(COMMON_CAMERA_KEYS[1:])}"
            )
        missing = [k for k in required if getattr(self, k) in (None, "")]
        if missing:
            field = type(self).model_fields.get(missing[0])
            what = f": {field.description}" if field is not None and field.description else ""
            raise ValueError(f"the {self.backend} camera backend needs {', '.join(missing)}{what}")
        return self


def _backend_keys(backend: str) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """The [camera] keys a backend reads beyond the common ones, and those it needs, from its record."""
    if backend in registry.provided_cameras():
        providers = [registry.load(n) for n in registry.names() if backend in registry.load(n).cameras]
        return tuple(dict.fromkeys(k for p in providers for k in p.camera_keys)), ()
    found = cameras.camera_backend(backend)
    return found.keys, found.required


def camera_keys(backend: str) -> tuple[str, ...] | None:
    """Every [camera] key ``backend`` reads (the common ones included), None for a backend not registered."""
    try:
        return COMMON_CAMERA_KEYS + _backend_keys(backend)[0]
    except CameraError:
        return None


def _shown(value: Any) -> str:
    return repr(list(value) if isinstance(value, tuple) else value)


def _owners(key: str) -> str:
    """Which camera backends read ``key``, for an error message: 'opencv and genicam read it'."""
    provided = [c for n in registry.names() if key in registry.load(n).camera_keys for c in registry.load(n).cameras]
    owners = [*cameras.readers(key), *dict.fromkeys(provided)]
    return f"{' and '.join(owners)} read{'s' if len(owners) == 1 else ''} it" if owners else ""
