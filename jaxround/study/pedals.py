"""The study's default pedal set-ups (``jaxround study serve --pedal-map``).

A JSON object from a gamepad's id (as the browser reports it, e.g.
``"G29 Driving Force Racing Wheel (Vendor: 046d Product: c24f)"``) to its
pedals, the same form the page's pedal set-up stores in the browser and
shows for copying::

    {"<gamepad id>": {"throttle": {"kind": "axis", "index": 2,
                                   "rest": 1.0, "pressed": -1.0},
                      "brake": {"kind": "axis", "index": 3,
                                "rest": 1.0, "pressed": -1.0}}}

A browser uses its own set-up of a pad first, then this file's.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

#: Raw values closer than this between rest and pressed cannot be a pedal.
MIN_TRAVEL = 0.2


class PedalInput(BaseModel):
    """An axis or button and its raw values at rest and pressed fully."""

    model_config = ConfigDict(extra="forbid")
    kind: Literal["axis", "button"]
    index: int = Field(ge=0, le=63)
    rest: float = Field(ge=-1.0, le=1.0)
    pressed: float = Field(ge=-1.0, le=1.0)

    @model_validator(mode="after")
    def _travels(self) -> PedalInput:
        if abs(self.pressed - self.rest) < MIN_TRAVEL:
            raise ValueError(
                f"rest {self.rest} and pressed {self.pressed} are closer than "
                f"{MIN_TRAVEL}"
            )
        return self


class PadPedals(BaseModel):
    """A gamepad's pedals: a throttle, a brake, or both."""

    model_config = ConfigDict(extra="forbid")
    throttle: PedalInput | None = None
    brake: PedalInput | None = None

    @model_validator(mode="after")
    def _some(self) -> PadPedals:
        if self.throttle is None and self.brake is None:
            raise ValueError("neither a throttle nor a brake")
        return self


def read_pedal_map(path: Path) -> dict[str, dict]:
    """The checked set-ups of `path`; ValueError naming what is wrong."""
    try:
        data = json.loads(Path(path).read_text())
    except OSError as err:
        raise ValueError(f"pedal map {path}: {err.strerror}") from None
    except json.JSONDecodeError as err:
        raise ValueError(f"pedal map {path}: not JSON ({err})") from None
    if not isinstance(data, dict) or not data:
        raise ValueError(f"pedal map {path}: expected an object of gamepad ids")
    checked = {}
    for pad_id, pedals in data.items():
        try:
            checked[pad_id] = PadPedals.model_validate(pedals).model_dump(
                exclude_none=True
            )
        except ValidationError as err:
            first = err.errors()[0]
            where = ".".join(str(x) for x in first["loc"])
            raise ValueError(
                f"pedal map {path}: {pad_id!r}{'.' + where if where else ''}: "
                f"{first['msg']}"
            ) from None
    return checked
