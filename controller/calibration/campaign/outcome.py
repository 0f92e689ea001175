"""How a campaign session ended: its :class:`CampaignResult`, the status and cause of a
session that ran to its end (``records.CAMPAIGN_STATUSES``, docs/campaigns.md), and whether a
heliostat's run failed at the look itself (:func:`looked_and_failed`)."""

from __future__ import annotations

from dataclasses import dataclass

from controller.calibration.records import RunRecord


@dataclass
class CampaignResult:
    campaign_id: int
    name: str
    resumed: bool
    runs: list[RunRecord]  # every heliostat run of the campaign (earlier sessions too)
    makespan_s: float  # plant time of this session, first start to last end
    sequential_estimate_s: float  # same work one after another (sum of slews + occupancy)
    status: str = "finished"  # one of records.CAMPAIGN_STATUSES
    cause: str | None = None  # why it ended so (None when every heliostat was calibrated)
    session_runs: int = 0

    @property
    def exit_code(self) -> int:
        """The CLI's exit status for this outcome (docs/campaigns.md): 0 every heliostat
        calibrated, 3 some failed or did not converge, 1 aborted."""
        return {"finished": 0, "partial": 3}.get(self.status, 1)


def outcome(runs: list[RunRecord], queue: list[str], target_blocked: bool,
            done: str = "calibrated") -> tuple[str, str | None]:
    """Status and cause of a campaign session that ran to its end (records.CAMPAIGN_STATUSES);
    ``done``: what the campaign's heliostats were for (``measured`` in a planned night's pass)."""
    if target_blocked:
        return "aborted", ("a beam may have been left on the target (a heliostat could not be parked); "
                           "nobody else was sent onto it")
    failed = [r for r in runs if r.status not in ("calibrated", "measured")]
    missing = len(queue) - len(runs)
    if not failed and not missing:
        return "finished", None
    parts = [f"{len(failed)} of {len(queue)} heliostats not {done}"] if failed else []
    if missing:
        parts.append(f"{missing} not recorded")
    detail = "; ".join(f"{r.heliostat_id}: {r.fault_cause or r.status.replace('_', ' ')}" for r in failed[:3])
    return "partial", ", ".join(parts) + (f" ({detail}{'; …' if len(failed) > 3 else ''})" if detail else "")


# The states of a cycle that look at the beam on the target: capture merged, analysed, matched, verified.
LOOK_STATES = ("merging", "analysing", "matching", "verifying")


def looked_and_failed(run: RunRecord) -> bool:
    """Whether ``run`` put its beam on the target, captured, and got no measurement from the look
    (no beam; a spot clipped at the view's edge; a frame that could not be analysed) — not a
    drive, camera or operator stop. Its frames are archived (``run_frames``) and, in a planned
    night, its geometry counts as failed (docs/nights.md, "Flagged geometries")."""
    return (run.status in ("failed", "no_beam") and run.on_target_s is not None
            and run.fault_state in LOOK_STATES)
