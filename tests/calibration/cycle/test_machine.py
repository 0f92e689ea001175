"""The calibration state machine: table, diagram, convergence, faults, timeouts, beam safety."""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from controller.calibration.campaign.runner import INTERRUPTED
from controller.calibration.cycle.beam_safety import UnsafePath
from controller.calibration.cycle.diagram import state_machine_markdown
from controller.calibration.cycle.gate import TargetGate
from controller.calibration.cycle.machine import FINAL_STATES, STATES, TRANSITIONS
from controller.recognition.library import Match
from simplant.clock import PlantClock
from tests.calibration.conftest import SPEEDUP
from tests.conftest import scaled_s

REPO = Path(__file__).resolve().parents[3]
MATCH = Match("wind-load", 0.4, "gravity-sag", 1.3)


def run_in_thread(fn):
    out: dict = {}
    t = threading.Thread(target=lambda: out.setdefault("r", fn()), daemon=True)
    t.start()
    return t, out


def test_diagram_doc_is_current():
    doc = (REPO / "docs" / "state-machine.md").read_text(encoding="utf-8")
    assert doc == state_machine_markdown(), "regenerate: python -m controller.calibration.cycle.diagram"
    assert "stateDiagram-v2" in doc


def test_table_is_complete():
    names = [s for s, _, _ in STATES]
    required = {"idle", "preparing", "slewing", "settling", "capturing", "merging", "analysing", "matching",
                "searching", "correcting", "verifying", "done", "standby", "fault", "stowed", "aborted"}
    assert set(names) == required and len(names) == len(required)
    assert all(t > 0 for _, t, _ in STATES), "every state has a timeout"
    for trig, src, dst in TRANSITIONS:
        for s in (src if isinstance(src, tuple) else (src,)):
            assert s in names, (trig, s)
        assert dst in names
    # every non-final state can fail into fault and can time out
    fail_src = next(s for t, s, _ in TRANSITIONS if t == "fail")
    assert set(names) - set(FINAL_STATES) - {"fault"} == set(fail_src)


def test_converges_and_parks(make_cycle):
    # hidden offset (150, -90) steps -> 30 mm / 22.5 mm on the target: about 0.64 mrad
    cyc, plant, drive = make_cycle(match=MATCH)
    rec = cyc.run()
    assert rec.status == "calibrated" and rec.final_state == "done"
    assert plant.true_errors[0] > 0.5 and len(plant.true_errors) == rec.iterations
    assert rec.error_after_mrad <= 0.3 and plant.true_errors[-1] <= 0.3
    assert rec.iterations == len(rec.measurements) >= 2
    assert [c.kind for c in rec.corrections] == ["fine"] * (rec.iterations - 1)
    # the exact Jacobian fixes the hidden offset in one correction: (-150, +90) steps
    assert (rec.corrections[0].daz_steps, rec.corrections[0].del_steps) == (-150, 90)
    assert rec.matched_label == "wind-load"
    assert rec.model is not None and np.allclose(rec.model.params["steps"], [-150, 90], atol=1)
    # the beam was parked off the target at the end, and the target handed back
    assert (drive.status().az_steps, drive.status().el_steps) == plant.standby
    assert cyc.ctx.gate.holder is None and not cyc.ctx.gate.blocked


def test_fitted_model_gives_the_next_aim(make_cycle):
    cyc, _, _ = make_cycle()
    model = cyc.run().model
    cyc2, plant2, _ = make_cycle(model=model)
    rec = cyc2.run()
    assert rec.iterations == 1 and plant2.true_errors[0] < 0.05


def test_coarse_correction_from_the_library(make_cycle):
    m = Match("gear-backlash", 0.2, "wind-load", 0.9, correction_deg=(-0.15, 0.09))
    cyc, _, _ = make_cycle(match=m)
    rec = cyc.run()
    assert rec.corrections[0].kind == "coarse" and rec.corrections[0].daz_steps == -150
    assert all(c.kind == "fine" for c in rec.corrections[1:])
    assert rec.status == "calibrated"


def test_unknown_match_gets_no_coarse_correction(make_cycle):
    m = Match("gear-backlash", 9.0, "wind-load", 9.5, unknown=True, correction_deg=(1.0, 1.0))
    rec = make_cycle(match=m)[0].run()
    assert rec.matched_label == "unknown" and {c.kind for c in rec.corrections} == {"fine"}


def test_max_iterations(make_cycle):
    # 1 mm of measurement noise (~0.02 mrad) never gets below a 0.001 mrad tolerance
    cyc, plant, _ = make_cycle(tolerance_mrad=1e-3, max_iterations=3)
    plant.noise_m = 1e-3
    rec = cyc.run()
    assert rec.status == "not_converged" and rec.iterations == 3 and rec.final_state == "done"


def test_camera_fails(make_cycle):
    cyc, plant, drive = make_cycle()
    plant.camera_fail = 1
    rec = cyc.run()
    assert rec.status == "failed" and rec.fault_state == "capturing"
    assert "CameraError" in rec.fault_cause and "ccd2" in rec.fault_cause
    assert rec.final_state == "done"  # made safe: parked at standby
    assert (drive.status().az_steps, drive.status().el_steps) == plant.standby
    assert cyc.ctx.gate.holder is None and not cyc.ctx.gate.blocked


def once_moving_onto_target(cyc, plant, action):
    """A drive hook: ``action()`` once, at the first status poll that shows the axes moving
    onto the target (slewing), well away from standby."""
    done = []

    def hook(call, drive):
        if done or call != "status" or cyc.state != "slewing":
            return
        st = plant.ctl.status()
        if st["moving"] and abs(st["az_steps"] - plant.standby[0]) > 200:
            done.append(call)
            action()
    return hook


def test_preparing_waits_where_the_drive_stands_when_the_pointing_says_it_may(make_cycle):
    """``Pointing.may_wait_at`` true (parked beside the target already, its spot out of the view):
    *preparing* commands no move and the approach starts from where the drive
    stands; after the measurement the beam parks at standby as always."""
    cyc, plant, drive = make_cycle(match=MATCH)
    away = (plant.standby[0] - 3000, plant.standby[1] + 500)
    st = drive.move_and_wait(*away, timeout_s=60.0, time=cyc.ctx.time)
    here, asked, visited = (st.az_steps, st.el_steps), [], []
    cyc.ctx.pointing.may_wait_at = lambda pose, standby, aim, m: asked.append((pose, standby, aim, m)) or True
    real_move = drive._send_move_abs
    drive._send_move_abs = lambda az, el: (visited.append((cyc.state, (az, el))), real_move(az, el))[1]
    rec = cyc.run()
    assert here != plant.standby
    assert asked == [(here, plant.standby, cyc.aim, cyc.ctx.pointing.path_margin_m())]
    assert visited[0][0] == "slewing" and not [v for s, v in visited if s == "preparing"]
    assert rec.status == "calibrated" and rec.final_state == "done"
    assert (drive.status().az_steps, drive.status().el_steps) == plant.standby


def test_actuator_stalls_mid_move(make_cycle):
    cyc, plant, drive = make_cycle()
    drive.after.append(once_moving_onto_target(cyc, plant, lambda: plant.ctl.inject_stall("az")))
    rec = cyc.run()
    assert rec.status == "failed" and rec.fault_state == "slewing"
    assert "stall_az" in rec.fault_cause
    assert "clear_fault" in drive.calls and rec.final_state == "done"
    assert (drive.status().az_steps, drive.status().el_steps) == plant.standby


def test_a_fault_mid_move_parks_along_the_planned_path_from_where_the_drive_stands(make_cycle):
    """The fault path plans its slew to standby like ``preparing`` (``Pointing.path_to``: the beam
    must not sweep across another target or into a person zone), from the pose the drive reports
    after the fault, not from the last commanded one, and moves through every waypoint."""
    cyc, plant, drive = make_cycle()
    asked, visited = [], []

    def path_to(start, end):
        asked.append((cyc.state, tuple(start), tuple(end)))
        return [(start[0], end[1]), end]  # elevation first

    cyc.ctx.pointing.path_to = path_to
    real_move = drive._send_move_abs
    drive._send_move_abs = lambda az, el: (visited.append((cyc.state, (az, el))), real_move(az, el))[1]
    drive.after.append(once_moving_onto_target(cyc, plant, lambda: plant.ctl.inject_stall("az")))
    rec = cyc.run()
    assert rec.status == "failed" and rec.fault_state == "slewing" and rec.final_state == "done"
    (state, start, end), = [a for a in asked if a[0] == "fault"]
    assert end == plant.standby and start != plant.standby  # stopped part-way, away from standby
    assert [pose for st, pose in visited if st == "fault"] == [(start[0], end[1]), end]
    assert (drive.status().az_steps, drive.status().el_steps) == plant.standby


def test_firmware_power_cycles_mid_move(make_cycle):
    cyc, plant, drive = make_cycle()
    drive.after.append(once_moving_onto_target(cyc, plant, plant.ctl.power_cycle))
    rec = cyc.run()
    assert rec.status == "failed" and rec.fault_state == "slewing"
    assert "power_cycle" in rec.fault_cause
    assert rec.final_state == "done" and plant.ctl.faults == 0  # cleared, then parked
    assert (drive.status().az_steps, drive.status().el_steps) == plant.standby


def test_link_lost_mid_move_aborts_and_blocks_the_target(make_cycle):
    gate = TargetGate()
    cyc, plant, drive = make_cycle(gate=gate)
    drive.after.append(once_moving_onto_target(cyc, plant, lambda: setattr(drive, "link_lost", True)))
    rec = cyc.run()
    assert rec.status == "failed" and rec.final_state == "aborted" and rec.fault_state == "slewing"
    assert "LinkError" in rec.fault_cause and "stow failed" in rec.fault_cause
    # the beam may still be on the target: nobody else gets it
    assert gate.blocked
    assert gate.acquire(1, lambda: False) is False


def test_link_back_before_the_fault_handler_parks(make_cycle):
    cyc, plant, drive = make_cycle()
    drive.after.append(once_moving_onto_target(cyc, plant, lambda: setattr(drive, "link_lost", True)))
    plant.on_state.append(lambda state: state == "fault" and setattr(drive, "link_lost", False))
    rec = cyc.run()
    assert rec.status == "failed" and "LinkError" in rec.fault_cause
    assert rec.final_state == "done" and not cyc.ctx.gate.blocked
    assert (drive.status().az_steps, drive.status().el_steps) == plant.standby


def test_state_timeout_leads_to_fault(make_cycle):
    cyc, plant, drive = make_cycle(timeouts={"capturing": scaled_s(0.15)})
    # The capture blocks until the machine has left the state: only the timeout can end it.
    plant.camera_block = release = threading.Event()
    plant.on_state.append(lambda state: state == "fault" and release.set())
    rec = cyc.run()
    assert rec.status == "failed" and rec.fault_cause == "timeout in state capturing"
    assert rec.final_state == "done"
    assert (drive.status().az_steps, drive.status().el_steps) == plant.standby


def test_gate_serves_tickets_in_order():
    gate = TargetGate()
    order: list[int] = []

    def take(ticket):
        assert gate.acquire(ticket, lambda: False)
        order.append(ticket)
        gate.release(ticket)
    threads = [threading.Thread(target=take, args=(t,)) for t in (2, 1, 0)]
    for th in threads:
        th.start()
    for th in threads:
        th.join(scaled_s(5))
    assert order == [0, 1, 2]


def test_only_one_beam_on_the_target(make_cycle):
    """Three cycles in parallel share one gate and one plant clock: the recorded intervals
    from the approach command to the beam parked again never overlap."""
    gate, clock = TargetGate(), PlantClock(SPEEDUP)
    cycles = [make_cycle(gate=gate, ticket=i, hidden=(100 * (i + 1), -50), clock=clock)[0] for i in range(3)]
    runs = [run_in_thread(c.run) for c in cycles]
    for t, _ in runs:
        t.join(scaled_s(30))
    recs = sorted((out["r"] for _, out in runs), key=lambda r: r.on_target_s)
    assert all(r.status == "calibrated" for r in recs) and len(recs) == 3
    for a, b in zip(recs, recs[1:], strict=False):
        assert a.off_target_s is not None and a.off_target_s <= b.on_target_s, (a, b)
    assert [r.queue_index for r in recs] == [0, 0, 0] and gate.holder is None and not gate.blocked


def test_only_one_beam_check_fails_without_the_gate(make_cycle):
    """The same three cycles, each with its own gate: their target intervals do overlap, so
    the check above can fail."""
    clock = PlantClock(SPEEDUP)
    cycles = [make_cycle(gate=TargetGate(), ticket=0, hidden=(100 * (i + 1), -50), clock=clock)[0]
              for i in range(3)]
    runs = [run_in_thread(c.run) for c in cycles]
    for t, _ in runs:
        t.join(scaled_s(30))
    recs = sorted((out["r"] for _, out in runs), key=lambda r: r.on_target_s)
    assert any(a.off_target_s > b.on_target_s for a, b in zip(recs, recs[1:], strict=False))


def test_operator_abort_parks_the_beam(make_cycle):
    cyc, plant, drive = make_cycle()
    plant.on_state.append(lambda state: state == "settling" and cyc.request_abort(INTERRUPTED))
    rec = cyc.run()
    assert rec.status == "failed" and rec.fault_cause == INTERRUPTED
    assert rec.fault_state == "settling" and rec.final_state == "done"
    assert (drive.status().az_steps, drive.status().el_steps) == plant.standby


def test_emergency_abort_stops_where_it_is(make_cycle):
    cyc, plant, drive = make_cycle()
    drive.after.append(once_moving_onto_target(cyc, plant, lambda: cyc.request_abort("emergency stop",
                                                                                       safe=False)))
    rec = cyc.run()
    assert rec.final_state == "aborted" and rec.status == "failed" and "stop" in drive.calls
    st = drive.status()
    assert not st.moving and (st.az_steps, st.el_steps) != plant.standby
    assert cyc.ctx.gate.blocked  # the beam may be on the target: nobody else gets it


def test_a_clipped_spot_is_corrected_towards_and_not_recorded(make_cycle):
    """A spot clipped by the view's edge is no measurement: the cycle moves towards it and looks
    again (at most CLIPPED_LOOKS times), and only unclipped spots are recorded."""
    from dataclasses import replace


    cyc, plant, drive = make_cycle()
    real = cyc.ctx.analyze
    looks = []

    def first_clipped(hdr):
        obs = real(hdr)
        looks.append(obs)
        return replace(obs, clipped=("top",)) if len(looks) == 1 else obs

    cyc.ctx.analyze = first_clipped
    rec = cyc.run()
    assert rec.status == "calibrated" and rec.final_state == "done"
    assert len(looks) == rec.iterations + 1  # one look more than the recorded measurements
    assert [c.kind for c in rec.corrections][0] == "fine"


def test_a_spot_that_stays_clipped_faults(make_cycle):
    from dataclasses import replace

    from controller.calibration.cycle.machine import CLIPPED_LOOKS

    cyc, plant, drive = make_cycle()
    real = cyc.ctx.analyze
    cyc.ctx.analyze = lambda hdr: replace(real(hdr), clipped=("left",))
    rec = cyc.run()
    assert rec.status == "failed" and rec.iterations == 0
    assert f"after {CLIPPED_LOOKS} corrections" in rec.fault_cause
    assert len(rec.corrections) == CLIPPED_LOOKS and rec.final_state == "done"


@pytest.mark.parametrize("beam_left", [True, False])
def test_a_stowed_heliostat_hands_the_target_on_only_once_its_beam_is_off_it(make_cycle, beam_left):
    """No safe path to standby: the firmware's stow is not a beam-safe path, so the target is
    handed on only once the drive has arrived and the beam is off it; a stow that leaves the
    beam on the target keeps everyone off it."""
    gate = TargetGate()
    cyc, plant, drive = make_cycle(gate=gate)
    plant.camera_fail = 10  # a fault with the beam on the target

    def no_safe_path(start, end):
        raise UnsafePath("no slew to standby keeps the beam off the targets")

    pointing = cyc.ctx.pointing
    plant.on_state.append(lambda state: state == "fault" and setattr(pointing, "path_to", no_safe_path))
    if not beam_left:
        pointing.beam_on_target = lambda az, el, margin_m=2.0: True
    released = []
    release = gate.release
    gate.release = lambda ticket, beam_off_target=True: (released.append(drive.status()),
                                                          release(ticket, beam_off_target))
    rec = cyc.run()
    assert rec.final_state == "stowed" and "stowed" in rec.fault_cause and released
    st = released[0]
    assert st.in_position and not st.moving and (st.az_steps, st.el_steps) == (500, 500)
    assert gate.blocked is not beam_left


def test_a_refused_park_leaves_a_heliostat_where_its_beam_is_off_the_views(make_cycle):
    """Issue 42: a park refused for want of a beam-safe slew (UnsafePath), from a pose whose beam
    is off every target's view, leaves the heliostat there. The firmware's stow would sweep the
    beam unchecked and could leave it in a view where other beams are measured."""
    gate = TargetGate()
    cyc, plant, drive = make_cycle(gate=gate, initial=(600, 600))  # its beam far off the target
    pointing = cyc.ctx.pointing

    def no_safe_path(start, end):
        raise UnsafePath("no slew to standby keeps the beam off the targets")

    pointing.path_to = no_safe_path  # preparing's slew to standby is refused, and the fault's park
    before = drive.status()
    assert pointing.off_targets(before.az_steps, before.el_steps, pointing.view_margin_m())
    rec = cyc.run()
    st = drive.status()
    assert rec.status == "failed" and rec.final_state == "done"
    assert "no slew to standby" in rec.fault_cause and rec.fault_cause.endswith("stayed")
    assert (st.az_steps, st.el_steps) == (before.az_steps, before.el_steps) and not st.moving
    assert not gate.blocked
