"""Slots: the aim points of the K heliostats measured in one capture on a target.

With ``calibration.beams_per_target`` K > 1 (lamps at night, :mod:`controller.calibration.beams.policy`)
each heliostat of a capture is aimed at its own *slot*: K points on a grid centred on the
target, far enough apart that the predicted spots (:mod:`controller.geometry.spot`: the spot's
3σ extent plus 3σ of its position from the model's covariance) never overlap, even while each
is stepped by :func:`identity_step_m` to confirm whose spot is whose, and close enough that
every one stays inside the camera's view, ``planner.view_margin_m`` from its edge. Along each
axis, with r the largest reach of a spot (k (σ_spot + σ_pos), k = 3, Eq. 4 of spot.py) plus
the step:

    spacing ≥ 2 r + GAP_M,     |o_slot| + r + margin ≤ H                           (1)

When K slots do not fit the view, fewer do: the layout is the largest K' ≤ K that satisfies
(1), down to one slot at the target's centre. A pass's heliostats take slots in tiers, each
spaced for its own spots (:func:`pass_layout`); slots of two tiers whose cells overlap never
hold beams at once (:meth:`SlotLayout.conflicts`). The slots keep the closest spacing
s = 2 r + GAP_M: spread farther apart, the slots on one side of the target left no slew to
their standby point that keeps the beam off the targets, and their heliostats had to take the
target alone.

A spot is looked for in its *window*, r each side of its slot, and registered and measured in
its *cell* (everything else flattened to the background,
:func:`controller.imaging.spots.isolate`): up to ``GAP_M``/2 from the midline to the next slot
along each axis, or the view's edge on a side that faces no other slot,

    cell = [o − s/2 + GAP/2  or  −H,   o + s/2 − GAP/2  or  +H]  along each axis     (2)

Real spots are often larger than predicted — a canting error splits one in two, a wind load
streaks it over metres — and the cell keeps what reaches beyond the window towards the
view's edge.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from controller.calibration.cycle.pointing import model_covariance
from controller.calibration.records import ModelRecord
from controller.config import PlantConfig
from controller.geometry.kinematics import HeliostatKinematics
from controller.geometry.pose_batch import KinStack, aim_steps
from controller.geometry.spot import SIGMAS, MirrorOptics, predict_spots
from controller.geometry.target_frame import TargetFrame

IDENTITY_STEP_M = 0.3  # how far a heliostat's known step moves its spot on the target, at least, m
# ... and at least this many of the view's pixels: a step under a pixel of a coarse camera (a
# 48 m view on 128 pixels: 0.375 m each) was not told from the others' in a third of the spots.
STEP_PX = 3.0
GAP_M = 0.2  # clear space between two slots' 3σ footprints, m
# A round of K beams against one beam alone, in target time (Eq. 3): the identity step, its
# settling and the second frame on top of the approach, capture and departure.
ROUND_COST = 1.5


@dataclass(frozen=True, eq=False)  # numpy fields
class SlotLayout:
    """S slot aim points: offsets (S, 2) m from the target centre along the view's (u, v), the
    aim points (S, 3) m ENU, the spot reach (S, 2) m each was spaced for (Eq. 1, without the
    step), each slot's cell (S, 4) m, (u0, u1, v0, v1) from the target centre (Eq. 2), and the
    identity step they were spaced for, m (:func:`identity_step_m`). ``tiers`` (S,): the tier
    of each slot (:func:`pass_layout`: a tier's slots are one grid, spaced for its spots; one
    tier by default); slots of different tiers whose cells overlap never hold beams at once
    (:meth:`conflicts`)."""

    offsets_m: np.ndarray
    aims_enu: np.ndarray
    reach_m: np.ndarray
    cells_m: np.ndarray
    step_m: float = IDENTITY_STEP_M
    tiers: np.ndarray | None = None

    @property
    def slots(self) -> int:
        return len(self.offsets_m)

    @property
    def k(self) -> int:
        """The most beams on the target at once: the largest tier's slots."""
        return max(self.tier_sizes)

    @property
    def tier_sizes(self) -> list[int]:
        """The slots of each tier."""
        return [int(n) for n in np.bincount(self.tier_of)]

    @property
    def tier_of(self) -> np.ndarray:
        return np.zeros(self.slots, int) if self.tiers is None else np.asarray(self.tiers, int)

    def tier_slots(self, tier: int) -> tuple[int, ...]:
        """The slots of ``tier`` (none for −1: the target alone)."""
        return tuple(int(s) for s in np.flatnonzero(self.tier_of == tier))

    def rank(self, slot: int) -> tuple[int, int]:
        """(i, n): ``slot`` is the i-th of its tier's n slots (the identity step's direction,
        :func:`controller.calibration.beams.identity.identity_step`)."""
        same = self.tier_slots(int(self.tier_of[slot]))
        return same.index(slot), len(same)

    def conflicts(self) -> dict[int, frozenset[int]]:
        """Each slot → the slots (itself included) whose cells overlap its own: never two beams
        at once (:class:`controller.calibration.cycle.gate.TargetGate`). Within a tier the cells
        only touch (Eq. 2), so only slots of other tiers conflict."""
        c = np.asarray(self.cells_m, float)
        over = ((np.minimum(c[:, None, 1], c[None, :, 1]) > np.maximum(c[:, None, 0], c[None, :, 0]))
                & (np.minimum(c[:, None, 3], c[None, :, 3]) > np.maximum(c[:, None, 2], c[None, :, 2])))
        return {s: frozenset(int(t) for t in np.flatnonzero(over[s])) for s in range(self.slots)}

    def aim(self, slot: int) -> tuple[float, float, float]:
        return tuple(float(x) for x in self.aims_enu[slot])

    @staticmethod
    def joined(layouts: list[SlotLayout]) -> SlotLayout:
        """One layout of the tiers ``layouts`` (each one tier, in this order)."""
        return SlotLayout(np.concatenate([x.offsets_m for x in layouts]),
                          np.concatenate([x.aims_enu for x in layouts]),
                          np.concatenate([x.reach_m for x in layouts]),
                          np.concatenate([x.cells_m for x in layouts]), layouts[0].step_m,
                          np.concatenate([np.full(x.slots, i) for i, x in enumerate(layouts)]))


def spot_reaches_m(cfg: PlantConfig, target_id: str, lamp_id: str, heliostats: dict[str, ModelRecord | None],
                   at_enu) -> np.ndarray:
    """Each heliostat's k-σ reach (spot extent plus position uncertainty, (H, 2) m along u, v,
    in the order of ``heliostats``: id → latest model) aimed at ``at_enu`` on ``target_id``
    under lamp ``lamp_id`` (:func:`controller.geometry.spot.predict_spots`, every heliostat at
    once over a :class:`controller.geometry.pose_batch.KinStack`); inf for one whose aim is
    out of reach."""
    ids = list(heliostats)
    if not ids:
        return np.zeros((0, 2))
    frame = target_frame(cfg, target_id)
    lamp = np.asarray(cfg.light_source(lamp_id).position_enu_m, float)
    hs = [cfg.heliostat(hid) for hid in ids]
    kin = KinStack.of([HeliostatKinematics.from_config(h) for h in hs])
    pairs = [model_covariance(heliostats[hid], cfg.calibration.model) for hid in ids]
    values = np.array([m.values for m, _ in pairs])
    aims = np.broadcast_to(np.asarray(at_enu, float), (len(ids), 1, 3))
    steps, ok = aim_steps(kin.shaped(2), values[:, None, :], aims, lamp=lamp)
    sp = predict_spots(kin, MirrorOptics.stack([h.mirror for h in hs]), values,
                       np.array([c for _, c in pairs]), steps, aims, frame, lamp=lamp,
                       lamp_diameter_m=cfg.light_source(lamp_id).diameter_m, lamp_image=True)
    reach = SIGMAS * (sp.sigma_m[:, 0] + sp.position_sigma_m[:, 0])
    return np.where(ok[:, :1] & np.isfinite(reach), reach, np.inf)


def spot_reach_m(cfg: PlantConfig, target_id: str, lamp_id: str, heliostats: dict[str, ModelRecord | None],
                 at_enu) -> np.ndarray:
    """The largest reach (2,) m of :func:`spot_reaches_m` over ``heliostats``."""
    return np.max(spot_reaches_m(cfg, target_id, lamp_id, heliostats, at_enu), axis=0, initial=0.0)


def pass_layout(frame: TargetFrame, k: int, reaches: np.ndarray, margin_m: float
                ) -> tuple[SlotLayout, np.ndarray]:
    """The slots of a pass whose heliostats' spots reach ``reaches`` (H, 2) m
    (:func:`spot_reaches_m`), in tiers, and each heliostat's tier (H,) int (−1: it takes the
    target alone). The largest spot need not set every round's spacing: a pass of 3,000
    heliostats under a far lamp has spots from 9 to 15 m across, and one spacing for all of
    them measured a third of the pass a beam at a time. For n = K, K − 1, …, 2, the heliostats
    not yet in a tier whose own reach lets n slots fit the view (Eq. 1, :func:`fits_slots`) form
    the n-slot tier, spaced for the largest of them on each axis (Eq. 1 holds per axis, so it
    holds for that too); those that fit no two slots take the target alone. Each tier costs

        T = Σ_tiers n_t · c(K_t) + n_alone,    c(1) = 1,   c(K') = ROUND_COST / K'         (3)

    in units of one measurement alone (:func:`layout_cost`): a round of K' beams costs
    :data:`ROUND_COST` times one beam's (the identity step, its settling and the second frame).
    Taking every heliostat into the largest tier it fits is least by Eq. (3), c falling with K'.
    Nobody in reach of two slots: one slot, everybody alone."""
    reaches = np.asarray(reaches, float)
    step = identity_step_m(frame)
    member = np.full(len(reaches), -1)
    tiers: list[SlotLayout] = []
    for n in range(k, 1, -1):
        new = (member < 0) & fits_slots(frame, n, reaches, margin_m, step)
        if new.any():
            member[new] = len(tiers)
            tiers.append(slot_layout(frame, n, reaches[new].max(axis=0), margin_m, step))
    if not tiers:
        return slot_layout(frame, 1, np.zeros(2), margin_m), member
    return SlotLayout.joined(tiers), member


def layout_cost(layout: SlotLayout, member: np.ndarray) -> float:
    """T of :func:`pass_layout`'s Eq. (3): the target time of a pass laid out so (``member``:
    each heliostat's tier, −1 alone), in units of one measurement alone."""
    size = np.array(layout.tier_sizes, float)
    cost = np.where(size == 1, 1.0, ROUND_COST / size)
    m = np.asarray(member, int)
    return float(cost[m[m >= 0]].sum() + (m < 0).sum())


def lamp_rate(cfg: PlantConfig, lamp_id: str, passes: list[tuple[str, list[str]]],
              models: dict[str, ModelRecord | None], k: int) -> float:
    """Measurements per single-beam measurement time that a lamp's ``passes`` ((target id,
    heliostat ids), the targets in parallel) would make with ``models`` now at K = ``k``: their
    heliostats over the busiest target's time, each pass laid out by :func:`pass_layout`
    (Eq. 3). A lamp whose spots are known well enough for full rounds rates K / ROUND_COST; one
    measured a beam at a time, 1 per target."""
    busy: dict[str, float] = {}
    n = 0
    for target_id, ids in passes:
        reach = spot_reaches_m(cfg, target_id, lamp_id, {h: models.get(h) for h in ids},
                               cfg.target(target_id).center_enu_m)
        layout, member = pass_layout(target_frame(cfg, target_id), k, reach,
                                     cfg.calibration.planner.view_margin_m)
        busy[target_id] = busy.get(target_id, 0.0) + layout_cost(layout, member)
        n += len(ids)
    return n / max(busy.values()) if busy and max(busy.values()) > 0 else 0.0


def identity_step_m(frame: TargetFrame) -> float:
    """How far the identity step moves a spot on ``frame``'s target, m: :data:`IDENTITY_STEP_M`,
    or :data:`STEP_PX` of the view's pixels (the smaller side's) when that is more."""
    rows, cols = frame.shape
    return max(IDENTITY_STEP_M, STEP_PX * min(frame.width_m / cols, frame.height_m / rows))


def target_frame(cfg: PlantConfig, target_id: str) -> TargetFrame:
    cam = cfg.camera_of(target_id)
    return TargetFrame.from_config(cfg.target(target_id), (cam.height_px, cam.width_px))


def _grid(n: int) -> tuple[int, int]:
    """(columns, rows) of an n-slot grid: ⌈√n⌉ columns."""
    cols = math.ceil(math.sqrt(n))
    return cols, math.ceil(n / cols)


def fits_slots(frame: TargetFrame, n: int, reach_m, margin_m: float, step_m: float) -> np.ndarray:
    """Whether an n-slot grid (Eq. 1) fits ``frame``'s view for spots of reach ``reach_m``
    (..., 2) m stepped by ``step_m``: along each axis, with c slots along it spaced
    s = 2 (r + step) + GAP_M about the centre, the outermost's |o| + r + step + margin =
    c (r + step) + (c − 1) GAP_M / 2 + margin ≤ H. One slot always fits."""
    r = np.asarray(reach_m, float) + step_m
    if n == 1:
        return np.ones(r.shape[:-1], bool)
    along = np.array(_grid(n), float)
    half = np.array([frame.width_m, frame.height_m]) / 2.0
    with np.errstate(invalid="ignore"):  # an infinite reach fits nothing
        return np.all(along * r + (along - 1.0) * GAP_M / 2.0 + margin_m <= half, axis=-1)


def slot_layout(frame: TargetFrame, k: int, reach_m, margin_m: float, step_m: float | None = None
                ) -> SlotLayout:
    """The largest layout of at most ``k`` slots satisfying Eq. (1) in ``frame``'s view for spots
    of reach ``reach_m`` (2,) m, each stepped by up to ``step_m`` (default
    :func:`identity_step_m`); a grid of ⌈√K⌉ columns."""
    step_m = identity_step_m(frame) if step_m is None else step_m
    r = np.asarray(reach_m, float) + step_m
    half = np.array([frame.width_m, frame.height_m]) / 2.0
    spacing = 2.0 * r + GAP_M
    for n in range(k, 0, -1):
        if not fits_slots(frame, n, reach_m, margin_m, step_m):
            continue
        cols, rows = _grid(n)
        cu = (np.arange(cols) - (cols - 1) / 2.0) * spacing[0]
        cv = (np.arange(rows) - (rows - 1) / 2.0) * spacing[1]
        offsets = np.array([(u, v) for v in cv for u in cu][:n])
        lo = np.where(offsets <= offsets.min(axis=0), -half, offsets - spacing / 2 + GAP_M / 2)  # Eq. (2)
        hi = np.where(offsets >= offsets.max(axis=0), half, offsets + spacing / 2 - GAP_M / 2)
        cells = np.stack([lo[:, 0], hi[:, 0], lo[:, 1], hi[:, 1]], axis=1)
        aims = frame.center + offsets[:, :1] * frame.u + offsets[:, 1:] * frame.v
        return SlotLayout(offsets, aims, np.broadcast_to(np.asarray(reach_m, float), (n, 2)).copy(),
                          cells, step_m)
    raise AssertionError("unreachable: one slot always fits")


def assign_slots(candidates: Sequence[Sequence[int]], fits: Callable[[int, int], bool]) -> list[int | None]:
    """The slot of each ticket in queue order (None: no slot fits it, it takes the target
    alone), ``candidates[t]`` the slots open to ticket t (its tier's, :meth:`SlotLayout.tier_slots`;
    none: it takes the target alone), ``fits(ticket, slot)`` telling whether a slot's pose suits
    the ticket's heliostat (:func:`controller.calibration.beams.group.slot_parks`). Each ticket
    takes, of its slots that fit it, the one left longest ago: tickets that every slot of K fits
    get 0, 1, …, K − 1, 0, 1, … (ticket t waits for t − K, the rounds stay full), and a
    heliostat that one slot does not suit takes the next instead of the target to itself, the
    ticket after it taking the slot it skipped. ``fits`` is asked in that order and no further
    than needed."""
    last: dict[int, int] = {}
    out: list[int | None] = []
    for t, open_ in enumerate(candidates):
        slot = next((s for s in sorted(open_, key=lambda s: (last.get(s, -1), s)) if fits(t, s)), None)
        if slot is not None:
            last[slot] = t
        out.append(slot)
    return out
