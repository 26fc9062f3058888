"""Messages of the fleet soil map service (``soilocp service map``, docs/map.md).

Keys (built by :mod:`soilocp.schemas.keys`)::

    soilocp/<vid>/soil                  SoilEstimate (input: every vehicle's, subscribed as soilocp/*/soil)
    soilmap/<map_id>/cells              MapCellUpdate, published after each committed batch (the acknowledgement)
    soilmap/<map_id>/query              queryable: ?frame=F;bbox=xmin,ymin,xmax,ymax -> MapQueryReply
    soilmap/<map_id>/rejected           MapRejection, one per refused estimate
    soilmap/<map_id>/status             MapStatus (publication every second and queryable)
    soilmap/<map_id>/alive              liveliness token
"""

from __future__ import annotations

from typing import Literal, Optional

from pydantic import BaseModel, ConfigDict, Field, model_validator

from soilocp.schemas.sensor import VehicleId

MAP_SCHEMA_VERSION = 1
MAP_ID_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"
#: The frame name of WGS84 cells (H3 hexagons); local frames are square cells.
WGS84 = "wgs84"

MapRejectionCode = Literal[
    "malformed_json",  # not JSON / not UTF-8
    "schema",  # not a SoilEstimate (missing / extra / wrong-typed field)
    "non_finite",  # NaN or inf
    "out_of_range",  # K, its band or a position outside plausible limits
    "vehicle_mismatch",  # payload vehicle_id is not the vehicle of the key it came on
    "bad_key",  # not soilocp/<vid>/soil
    "inconsistent",  # e.g. a place whose patch list does not match its wheels
]


class _MapMessage(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    schema_version: Literal[1] = MAP_SCHEMA_VERSION


class MapCell(_MapMessage):
    """One cell of the map: the fused soil strength of the estimates made in it (inverse variance
    in ln K over the latest estimate of each vehicle, each aged by the map's ageing rate)."""

    cell: str = Field(description="Cell id: an H3 index (frame wgs84) or '<frame>/<size>/<ix>/<iy>' (square)")
    frame: str = Field(description="wgs84 (H3 hexagon) or the local frame's name (square cell)")
    center: tuple[float, float] = Field(description="Cell centre: (x, y) m in the frame, or (longitude, latitude) deg")
    K: float = Field(gt=0, description="Fused soil strength (exp of the fused ln K)")
    log_k_std: float = Field(gt=0, description="1-sigma of the fused ln K, aged to the reply's time")
    K_lo: float = Field(gt=0, description="Lower end of the 95 % band, exp(ln K - 1.96 sigma)")
    K_hi: float = Field(gt=0, description="Upper end of the 95 % band, exp(ln K + 1.96 sigma)")
    count: int = Field(ge=1, description="Estimates applied to the cell (all vehicles)")
    last_seen: float = Field(description="Wall-clock time (map service) of the newest estimate, s since the epoch")
    vehicles: list[VehicleId] = Field(description="The vehicles whose estimates the cell holds, sorted")


class MapCellUpdate(_MapMessage):
    """Published after each committed batch: what is now durably in the map."""

    map_id: str = Field(pattern=MAP_ID_PATTERN, description="The map this service keeps (its keys' soilmap/<map_id>/...)")
    batch: int = Field(ge=1, description="Commit counter of this service run")
    applied: dict[str, tuple[int, int]] = Field(
        description="Per vehicle: (the last seq committed in this batch, the vehicle's total committed updates)")
    cells: list[MapCell] = Field(description="The cells this batch changed, as they now are")
    time: float = Field(description="Wall-clock time of the commit, s since the epoch")


class MapCellColumns(BaseModel):
    """Cells as columns (one list per MapCell field, the same length): a box may hold ten thousand
    cells, and columns cost a fraction of objects to write and to read."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    frame: str = Field(description="wgs84 (H3 hexagons) or the local frame's name (square cells)")
    cell: list[str] = Field(description="Cell ids, as MapCell.cell")
    cx: list[float] = Field(description="Cell centres: x m, or longitude deg for wgs84")
    cy: list[float] = Field(description="y m, or latitude deg")
    K: list[float] = Field(description="Fused soil strength per cell, as MapCell.K")
    log_k_std: list[float] = Field(description="1-sigma of the fused ln K per cell")
    K_lo: list[float] = Field(description="Lower ends of the 95 % bands")
    K_hi: list[float] = Field(description="Upper ends of the 95 % bands")
    count: list[int] = Field(description="Estimates applied per cell")
    last_seen: list[float] = Field(description="Wall-clock time of each cell's newest estimate, s since the epoch")
    vehicles: list[list[VehicleId]] = Field(description="The vehicles each cell's estimates came from, sorted")

    @model_validator(mode="after")
    def _same_length(self):
        n = len(self.cell)
        bad = [k for k in ("cx", "cy", "K", "log_k_std", "K_lo", "K_hi", "count", "last_seen", "vehicles")
               if len(getattr(self, k)) != n]
        if bad:
            raise ValueError(f"columns {bad} do not have the {n} entries of 'cell'")
        return self


class MapQueryReply(_MapMessage):
    map_id: str = Field(pattern=MAP_ID_PATTERN, description="The map this service keeps (its keys' soilmap/<map_id>/...)")
    frame: str = Field(description="The frame the box and the cells are in")
    bbox: tuple[float, float, float, float] = Field(description="xmin, ymin, xmax, ymax (lon/lat deg for wgs84)")
    columns: MapCellColumns = Field(description="Cells whose centre lies in the box, ordered by centre (x, then y), "
                                    "aged to 'time'")
    truncated: bool = Field(description="True when more cells matched than the limit")
    time: float = Field(description="The time the cells are aged to, s since the epoch")

    @property
    def cells(self) -> list[MapCell]:
        """The columns as MapCell models."""
        return [MapCell(cell=c, frame=self.columns.frame, center=(x, y), K=k, log_k_std=s, K_lo=lo, K_hi=hi,
                        count=n, last_seen=t, vehicles=v)
                for c, x, y, k, s, lo, hi, n, t, v in zip(
                    self.columns.cell, self.columns.cx, self.columns.cy, self.columns.K, self.columns.log_k_std,
                    self.columns.K_lo, self.columns.K_hi, self.columns.count, self.columns.last_seen,
                    self.columns.vehicles)]


class MapRejection(_MapMessage):
    map_id: str = Field(pattern=MAP_ID_PATTERN, description="The map this service keeps (its keys' soilmap/<map_id>/...)")
    vehicle_id: Optional[str] = Field(description="Vehicle of the key the estimate arrived on (null: unreadable key)")
    seq: Optional[int] = Field(default=None, description="seq of the refused estimate (null: unreadable)")
    code: MapRejectionCode = Field(description="Why it was refused, as a code")
    field: Optional[str] = Field(default=None, description="The field at fault (null: the whole payload)")
    message: str = Field(description="Why, in words: the value and what was expected")
    key: str = Field(description="The key the estimate arrived on")
    received_at: float = Field(description="Wall-clock time of reception, s since the epoch")


class MapStatus(_MapMessage):
    map_id: str = Field(pattern=MAP_ID_PATTERN, description="The map this service keeps (its keys' soilmap/<map_id>/...)")
    pid: int = Field(description="The map service's process id")
    store: str = Field(description="sqlite:<path> or postgresql://host/db")
    received: int = Field(ge=0, description="Estimates received")
    applied: int = Field(ge=0, description="Estimates committed to cells")
    skipped: dict[str, int] = Field(description="Valid estimates that carry nothing for the map, by reason "
                                    "(status not usable, no place, older than the cell's)")
    rejected: dict[str, int] = Field(description="Refused estimates by code")
    dropped: int = Field(ge=0, description="Estimates dropped because the worker queue was full")
    batches: int = Field(ge=0, description="Batches committed since the service started")
    cells: int = Field(ge=0, description="Cells in the store")
    queue_depth: int = Field(ge=0, description="Estimates waiting for the worker")
    time: float = Field(description="Wall-clock time of this report, s since the epoch")
