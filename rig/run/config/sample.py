"""The ``[sample]`` table of a rig file: the sample's shape, flat or a sphere or cylinder of given radius.

Its own module as ``[camera]`` is: the schema (``rig.run.config.schema``) holds the other tables; the geometry
itself is ``rig.instrument.sample_surface``.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from rig.run.config.strict import Strict

#: The largest radius a curved sample may have (mm): a half-metre ball is beyond any gonioreflectometer's stage.
MAX_SAMPLE_RADIUS_MM = 250.0


class Sample(Strict):
    """``[sample]``: the sample's shape (``rig.instrument.sample_surface``): "flat", or a "sphere" or "cylinder".

    ``radius_mm``: the sphere's or cylinder's radius in millimetres, required for them and refused for a flat
    sample. The sphere's top and the cylinder's top line touch where a flat sample's centre is; the
    cylinder's axis runs along the sample's bitangent (its local y) and is ``[geometry] sample_height_m`` long.
    """

    shape: Literal["flat", "sphere", "cylinder"] = "flat"
    radius_mm: Annotated[float, Field(gt=0, le=MAX_SAMPLE_RADIUS_MM, allow_inf_nan=False)] | None = None

    @model_validator(mode="after")
    def _radius_for_shape(self) -> Sample:
        if self.shape == "flat" and self.radius_mm is not None:
            raise ValueError(f"radius_mm = {self.radius_mm:g}: a flat sample has no radius; expected no radius_mm, "
                             "or shape = \"sphere\" or \"cylinder\"")  # fmt: skip
        if self.shape != "flat" and self.radius_mm is None:
            raise ValueError(f"shape = {self.shape!r}: a {self.shape} needs radius_mm (its radius in mm, "
                             f"> 0 and <= {MAX_SAMPLE_RADIUS_MM:g})")  # fmt: skip
        return self
