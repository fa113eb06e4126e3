"""Lockstep turns (``mavastsm.lockstep_turns``): the vehicle moves only while the bridge's acting threads wait for it.

Pure threading, no sockets: the test thread plays the bridge's reader (and the sim), a thread plays the start-up
thread. Every wait is on a condition with a timeout; nothing sleeps blind and nothing is timed."""

from __future__ import annotations

import threading

from mavastsm.lockstep_turns import LockstepTurns, TurnCondition

NEVER = threading.Event()


def _run(turns: LockstepTurns, body) -> threading.Thread:
    """``body()`` on a participant thread; returns once it has joined the turns."""
    joined = threading.Event()

    def participant():
        with turns.participant():
            joined.set()
            body()

    t = threading.Thread(target=participant, daemon=True)
    t.start()
    assert joined.wait(5.0)
    return t


def test_the_vehicle_waits_while_a_participant_runs_and_for_every_datagram_to_be_handled():
    turns = LockstepTurns()
    go = threading.Event()

    t = _run(turns, lambda: go.wait(5.0))  # running: not waiting for the vehicle
    assert not turns.settled(0, timeout_s=0.05)  # a participant runs
    go.set()
    t.join(5.0)
    assert turns.settled(0, timeout_s=5.0)
    assert not turns.settled(3, timeout_s=0.05)  # the sim sent 3 datagrams the reader has not handled
    turns.reader_handled(3)
    assert turns.settled(3, timeout_s=5.0)


def test_a_vehicle_clock_sleep_ends_at_the_first_sample_that_reaches_it():
    turns = LockstepTurns()
    turns.vehicle_sample(1.0)
    woke_at: list[float] = []

    def body():
        turns.sleep(0.010, NEVER)  # 10 ms of vehicle time: four 2.5 ms samples
        woke_at.append(turns.vehicle_time_s)

    t = _run(turns, body)
    assert turns.settled(0, timeout_s=5.0)  # it sleeps: the vehicle may move
    for k in range(1, 9):  # the reader, sample by sample: each one waits until the participants wait again
        turns.vehicle_sample(1.0 + 0.0025 * k)
        turns.settle(lambda: False)
    t.join(5.0)
    assert woke_at == [1.0 + 0.0025 * 4]


def test_a_reply_wakes_its_waiter_and_the_reader_goes_on_only_once_it_has_acted():
    turns = LockstepTurns()
    cond = TurnCondition(turns)
    replies: list[int] = []
    order: list[str] = []

    def body():
        with cond:
            cond.wait_for(lambda: replies, 5.0)
        order.append("the next command")  # what the start-up thread does on the reply, before the sample's answer

    t = _run(turns, body)
    assert turns.settled(0, timeout_s=5.0)  # it waits for the reply
    with cond:  # the reader: the reply arrives
        replies.append(1)
        cond.notify_all()
    turns.settle(lambda: False)
    order.append("the answer to the next sample")
    t.join(5.0)
    assert order == ["the next command", "the answer to the next sample"]


def test_a_plain_condition_and_a_non_participant_are_untouched():
    plain = TurnCondition(None)
    with plain:
        assert plain.wait(0.0) is False
    turns = LockstepTurns()
    stop = threading.Event()
    stop.set()
    assert turns.sleep(10.0, stop) is True  # not a participant: the host's clock, ended by the stop at once
    assert turns.settled(0, timeout_s=0.0)
