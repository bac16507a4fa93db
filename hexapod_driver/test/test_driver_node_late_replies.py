"""The driver_node process against the emulated bus when replies come late: a slow USB adapter
(its latency timer), a reply stalled past the reply timeout at start-up, and replies later than
every attempt of a read. What the node concluded is checked against the emulator's log.

DDS stays on loopback (ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST) on the domain of the package's node tests.
"""
import math
import os
import re

import pytest

rclpy = pytest.importorskip('rclpy')
from sensor_msgs.msg import JointState  # noqa: E402
from test_driver_node import PARAMS, Inbox, comes_up_and_reads, command, request_of, sample_tick, start_node_env, wait_for  # noqa: E402

import hexapod_testing as testing  # noqa: E402
from hexapod_driver import protocol as p  # noqa: E402
from hexapod_driver.bus import EventKind  # noqa: E402
from hexapod_driver.config import DriverConfig  # noqa: E402
from hexapod_driver.emulator import BusEmulator  # noqa: E402
from hexapod_model import contract  # noqa: E402
from hexapod_msgs.msg import ReadSchedule  # noqa: E402

DOMAIN_ID = 20 + os.getpid() % 20          # 20..39: this package's node tests (start_node_env's)


def ping_round_trip_bounds(emu):
    """Bounds on the round trip of each start-up PING the driver timed, from the emulator's log
    alone, so they hold on a loaded host: (low, high) per PING [s].

    The driver times the first PING to each servo that is answered (then it READs the model
    number). Its round trip, from its write to its read of the reply, covers the emulator's own,
    from the instruction's arrival to the reply's write; and it lies between the write of the reply
    before (to the last READ of the servo before, which the driver took: it moved on) and the
    arrival of the READ after, which the driver sends only once it has the reply."""
    log = list(emu.log)
    end = next((k for k, e in enumerate(log) if e.instruction != p.PING and e.address not in (0, 16)), len(log) - 1)
    out = []
    for k, e in enumerate(log[:end]):
        before, after = log[k - 1] if k else None, log[k + 1]
        if (e.instruction != p.PING or after.instruction != p.READ or after.servo_id != e.servo_id
                or (before is not None and before.servo_id == e.servo_id)):
            continue
        took_before = before is not None and before.instruction == p.READ and before.replied
        out.append((e.wall_reply - e.wall, after.wall - before.wall_reply if took_before else math.inf))
    return out


def reply_timeout_s(baud_rate, latency_timer_ms, margin_ms, n=2):
    """The driver's reply timeout for a READ of ``n`` bytes (transport.py)."""
    return (n + 6) * p.BITS_PER_BYTE / baud_rate + (2.0 * latency_timer_ms + margin_ms) * 1e-3


def running_margin_ms():
    """The node's timeout_margin_ms in these tests (PARAMS)."""
    return float(next(a for a in PARAMS if a.startswith('timeout_margin_ms:=')).partition(':=')[2])


def test_late_replies_are_never_paired_with_the_wrong_request_and_the_cause_is_named(robot, ros):
    node, ex = ros
    latency_s = 0.016                                               # FTDI latency timer at its default
    with BusEmulator(robot) as emu:
        emu.faults.set_reply_latency(latency_s)
        proc, out = start_node_env(emu.port)
        inbox = Inbox(node)
        try:
            wait_for(ex, lambda: inbox.states and testing.logged(out.text(), EventKind.LATE_REPLIES), 60.0, proc,
                     'first reads')
            pings = ping_round_trip_bounds(emu)
            # now and then a reply later than the reply timeout (a USB stall), answered while the
            # driver waits for its next attempt: only the request/reply pairing keeps it apart
            widened_ms = float(re.search(r'widened .* to ([\d.]+)', testing.logged(
                out.text(), EventKind.LATE_REPLIES)[0]).group(1))
            timeout_s = reply_timeout_s(robot.bus.baud_rate, widened_ms, running_margin_ms())
            emu.faults.hold_replies(1.2 * timeout_s - latency_s, ids=1, count=None, probability=0.05)
            run_reads_of_a_moving_joint(robot, node, ex, emu, proc, inbox, 150)
        finally:
            rc, text = out.finish(proc, timeout=15.0)
            inbox.close(node)
    assert rc == 0, text
    late = testing.logged(text, EventKind.LATE_REPLIES)             # the cause is named, once
    assert len(late) == 1 and not testing.logged(text, EventKind.NO_READ_REPLIES), text   # and no other
    timed, rtt_ms, late_ms, new_ms = (float(re.search(pattern, late[0]).group(1)) for pattern in (
        r'fastest of (\d+) PING', r'PING round trips ([\d.]+) ms', r'~(\d+) ms late', r'widened .* to ([\d.]+)'))
    # The measured round trip is the one the emulator's log brackets (whatever the host's load added
    # on either side), and at least the adapter's latency: never a wire time, never a guess.
    assert pings and len(pings) == timed, (pings, text)                # the PINGs the driver timed, no other
    low, high = (min(b) * 1e3 for b in zip(*pings))                 # a[i] <= x[i] <= b[i]: so are the minima
    assert latency_s * 1e3 <= low, pings
    assert low - 0.1 <= rtt_ms <= high + 0.1, (low, rtt_ms, high, text)
    assert late_ms >= latency_s * 1e3 - 1.0 and new_ms >= late_ms / 2.0, text   # the timeout counts it twice
    assert any(e.servo_id == 1 and e.t_reply - e.t > timeout_s for e in emu.log)   # such replies came
    assert_each_sample_is_its_own_reads_answer(robot, emu, inbox)


def eeprom_writes(emu, sid):
    return sorted(e.address for e in emu.log if e.servo_id == sid and e.instruction == p.WRITE and e.address < 24)


def test_a_startup_read_answered_after_its_timeout_is_not_taken_for_status_return_level_0(robot, ros):
    # A stalled reply at start-up: the READ of servo 7's model number (after its PING: whether it
    # answers READs at all) and the READ of servo 8's status return level come after the reply timeout.
    node, ex = ros
    cfg = DriverConfig()
    late_s = 1.5 * reply_timeout_s(robot.bus.baud_rate, cfg.latency_timer_ms, cfg.startup_timeout_margin_ms)
    with BusEmulator(robot) as emu:
        emu.faults.hold_replies(late_s, ids=7, count=1, address=0)
        emu.faults.hold_replies(late_s, ids=8, count=1, address=16)
        rc, text = comes_up_and_reads(node, ex, emu.port, timeout=60.0)
    assert rc == 0, text
    assert not testing.logged(text, EventKind.NO_READ_REPLIES), text        # no "status return level 0?"
    assert not testing.logged(text, EventKind.STATUS_RETURN_LEVEL_SET), text
    assert not [e for e in emu.log if e.instruction == p.WRITE and e.address == 16]     # nor its EEPROM write
    assert eeprom_writes(emu, 7) == eeprom_writes(emu, 8) == eeprom_writes(emu, 9)      # what every servo gets
    for sid, address in ((7, 0), (8, 16)):
        reads = [e for e in emu.log if e.servo_id == sid and e.instruction == p.READ and e.address == address]
        held, retry = reads[0], reads[1]
        assert retry.t < held.t_reply, reads                        # the driver had given up on it and asked again
        assert held.replied and retry.replied and retry.data[0] != held.data[0], reads   # the retry a byte longer
    assert 'servos verified and configured' in text and 'Traceback' not in text, text
    assert all(s.get('status_return_level') == 2 for s in emu.servos)


def run_reads_of_a_moving_joint(robot, node, ex, emu, proc, inbox, n):
    """Read only leg1_coxa, which moves back and forth, until ``n`` of its samples are published."""
    cmd_pub = node.create_publisher(JointState, contract.JOINT_COMMANDS, 10)
    sched_pub = node.create_publisher(ReadSchedule, contract.READ_SCHEDULE, 10)
    sched = ReadSchedule()
    sched.joint_names = ['leg1_coxa']
    target = [0.8]

    def moving():
        tick = emu.present_tick(1)
        if abs(tick - round(512 + target[0] / robot.servo.rad_per_tick)) < 5:
            target[0] = -target[0]
        command(node, cmd_pub, ['leg1_coxa'], target)
        sched_pub.publish(sched)
        return sum(m.name[0] == 'leg1_coxa' for m in inbox.states) >= n
    try:
        wait_for(ex, moving, 90.0, proc, 'reads of the moving joint')
    finally:
        node.destroy_publisher(cmd_pub)
        node.destroy_publisher(sched_pub)


def assert_each_sample_is_its_own_reads_answer(robot, emu, inbox):
    ticks = set()
    for m in (m for m in inbox.states if m.name[0] == 'leg1_coxa'):
        e = request_of(emu, 1, contract.stamp_seconds(m.header.stamp))
        assert e is not None and e.replied, m
        assert sample_tick(robot, m) == e.reply_params[0] | e.reply_params[1] << 8, 'reply paired with another request'
        ticks.add(sample_tick(robot, m))
    assert len(ticks) > 20                                          # the joint really moved: pairing was testable


def test_a_reply_later_than_every_attempt_is_not_published_as_the_next_reads_position(robot, ros):
    node, ex = ros
    cfg = DriverConfig()
    attempts = 1 + cfg.read_retries
    timeout_s = reply_timeout_s(robot.bus.baud_rate, cfg.latency_timer_ms, running_margin_ms())
    with BusEmulator(robot) as emu:
        proc, out = start_node_env(emu.port)
        inbox = Inbox(node)
        try:
            wait_for(ex, lambda: len(inbox.states) > 20, 60.0, proc, 'first reads')
            # now and then a position reply stalled past all of its read's attempts: it comes
            # while the next read of the servo, for the same register, waits for its answer. When the
            # next read starts after the last attempt's timeout depends on the host's load, so the
            # stalls are of several lengths: some land inside a next read's wait on a busy machine too
            for extra in (0.25, 0.5, 1.0, 2.0):
                emu.faults.hold_replies((attempts + extra) * timeout_s, ids=1, count=None, probability=0.015,
                                        address=36)
            run_reads_of_a_moving_joint(robot, node, ex, emu, proc, inbox, 200)
        finally:
            rc, text = out.finish(proc, timeout=15.0)
            inbox.close(node)
    assert rc == 0, text
    reads = [e for e in emu.log if e.servo_id == 1 and e.instruction == p.READ and e.address == 36]
    came_during_the_next_read = [
        (held, reads[k + attempts]) for k, held in enumerate(reads[:-attempts])
        if held.t_reply - held.t > attempts * timeout_s
        and reads[k + attempts].t < held.t_reply < reads[k + attempts].t + timeout_s]
    assert came_during_the_next_read, 'no stalled reply came while the next read waited: nothing was tested'
    assert testing.logged(text, EventKind.READ_FAILED), text        # those reads failed, and were said to
    assert_each_sample_is_its_own_reads_answer(robot, emu, inbox)
