"""The hot folder's shot request: what a tethered camera without a trigger asks the tethering side to shoot.

A ``[camera] backend = "folder"`` camera with no ``trigger`` cannot make the camera fire; something else
must (the tethering program's own remote, a lab's script around a vendor SDK, a person at the camera, or
gonio's rehearsal rig, ``gonio sim rig``). So that it knows *what* to shoot, each capture leaves a request
in the folder: a hidden JSON file ``.gonio-shot-NNNNNN-PID.json`` holding ``index`` (frames asked for so
far), ``exposure_s`` (seconds), ``gain`` (linear), ``shutter`` and ``iso`` (as cameras write them). The
file is written atomically (a temporary name, then a rename) and removed by whoever shoots it, or by the
camera when it gives up waiting, so a request in the folder is always one that is still wanted. Hidden
names keep requests out of every frame pattern.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

from acquisition.frame import ExposureSettings

#: Request files: hidden, so no frame pattern matches them.
REQUEST_GLOB = ".gonio-shot-*.json"
#: The one version of the request's keys.
REQUEST_FORMAT = 1


@dataclass(frozen=True)
class ShotRequest:
    """One requested frame: its index, the exposure (s) and gain to shoot it at, and who asked (a process id)."""

    index: int
    exposure_s: float
    gain: float
    client: int = 0


def _shutter(exposure_s: float) -> str:
    """An exposure as cameras write it (``1/250``, ``0.5``): the trigger's own spelling."""
    from acquisition.cameras.trigger import shutter_text  # here: the trigger module is the spelling's home

    return shutter_text(exposure_s)


def write_request(folder: Path, settings: ExposureSettings, index: int, client: int | None = None) -> Path:
    """Leave a request for frame ``index`` at ``settings`` in ``folder``, atomically; returns its path.

    ``client`` names the controller asking (its process id, this process's by default).
    """
    name = f".gonio-shot-{index:06d}-{os.getpid() if client is None else client}.json"
    path = folder / name
    staging = folder / f"{name}.part"
    body = {"format": REQUEST_FORMAT, "index": index, "exposure_s": settings.exposure_s, "gain": settings.gain,
            "shutter": _shutter(settings.exposure_s), "iso": round(100 * settings.gain)}  # fmt: skip
    staging.write_text(json.dumps(body) + "\n")
    os.replace(staging, path)
    return path


def withdraw_request(path: Path) -> None:
    """Take back a request nobody answered (it must not be shot later, into another capture's wait)."""
    path.unlink(missing_ok=True)


def take_requests(folder: Path) -> list[ShotRequest]:
    """Claim the requests now in ``folder``, oldest first, removing each (the tethering side's call).

    A request file that is not gonio's format is removed and skipped: a tethering program must not fire
    on what it cannot read.
    """
    taken = []
    for path in sorted(folder.glob(REQUEST_GLOB)):
        try:
            body = json.loads(path.read_text())
        except (OSError, ValueError):
            body = None
        try:
            path.unlink()
        except FileNotFoundError:  # claimed by another reader, or withdrawn, between the listing and now
            continue
        if isinstance(body, dict) and body.get("format") == REQUEST_FORMAT:
            try:
                client = int(path.stem.rsplit("-", 1)[-1])
                taken.append(ShotRequest(int(body["index"]), float(body["exposure_s"]), float(body["gain"]), client))
            except (KeyError, TypeError, ValueError):
                continue
    return taken
