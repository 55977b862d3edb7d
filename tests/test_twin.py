"""A second world in our namespace (world_node.twin): of two worlds the one that steps goes on, of two waiting
exactly one refuses, decided alike on both sides; a writer of heartbeats that is no world node neither stops
nor holds back a world. The rule alone first, then on rclpy at every timing: two worlds waiting, a second
started within a second of the first, beside a system from its first step and long after, and a squatter."""

from __future__ import annotations

import contextlib

import pytest
import rclpy
from hypothesis import given
from hypothesis import strategies as st
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from helpers import GRID, RUN_TIMEOUT_S, finish, offline_rows, parameters, unique, wait_until
from msgs_spec import HEARTBEAT, HEARTBEAT_TOPIC, WORLD_STATS, WORLD_STATS_TOPIC, Heartbeat, encode, new_key_file
from node_runtime.qos import profile
from node_runtime.graph import UNKNOWN_NODE
from world_node import WorldNode
from world_node.twin import HEARD_FOR_BEATS, KEPT, Identity, Twins

NS = "/run7"
WORLD = ("world", NS, b"gid")


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def world(started: int, ticket: int, clock=None) -> Twins:
    return Twins(Identity(started, ticket), "world", NS, beat_period=1.0, clock=clock or Clock())


def beat(of: Twins, stepping: bool, n: int = 1) -> Heartbeat:
    return Heartbeat(n, 0, 0, int(stepping), of.me.started, of.me.ticket)


BOTH = [WORLD, ("world", NS, b"other gid")]  # the graph shows two writers of world/heartbeat named /run7/world


def test_a_waiting_world_refuses_beside_one_that_steps_and_the_stepping_one_goes_on():
    running, newcomer = world(1000, 5), world(1060, 3)
    newcomer.heard(beat(running, stepping=True))
    running.heard(beat(newcomer, stepping=False))
    said = newcomer.refusal(False, BOTH)
    assert said and "another node named /run7/world" in said and "steps" in said and "refusing to start" in said
    assert running.refusal(True, BOTH) is None


def test_a_stepping_world_goes_on_even_beside_a_waiting_twin_that_ranks_before_it():
    stepping, earlier = world(1060, 3), world(1000, 5)
    stepping.heard(beat(earlier, stepping=False))
    assert stepping.refusal(True, BOTH) is None
    earlier.heard(beat(stepping, stepping=True))
    assert earlier.refusal(False, BOTH)  # the waiting one refuses, though it started first


def test_of_two_stepping_worlds_the_later_started_yields():
    first, later = world(1000, 9), world(1001, 1)
    first.heard(beat(later, stepping=True))
    later.heard(beat(first, stepping=True))
    assert first.refusal(True, BOTH) is None
    said = later.refusal(True, BOTH)
    assert said and "started before this one" in said and "yielding" in said


@given(st.integers(0, 2**31 - 1), st.integers(0, 2**31 - 1), st.integers(0, 2), st.integers(0, 2**31 - 1),
       st.booleans(), st.booleans())
def test_two_worlds_never_both_refuse_and_a_stepping_one_yields_only_to_an_earlier_stepping_one(
        started, ticket, later_by, other_ticket, a_steps, b_steps):
    a, b = world(started, ticket), world(started + later_by, other_ticket)
    if (a.me.started, a.me.ticket) == (b.me.started, b.me.ticket):
        return  # one world, not two
    a.heard(beat(b, b_steps))
    b.heard(beat(a, a_steps))
    refused = [a.refusal(a_steps, BOTH) is not None, b.refusal(b_steps, BOTH) is not None]
    assert refused != [True, True]
    if not a_steps and not b_steps:
        assert sum(refused) == 1  # of two waiting, exactly one
        assert refused == [b.me.before(a.me.started, a.me.ticket), a.me.before(b.me.started, b.me.ticket)]
    if a_steps != b_steps:
        assert refused == [not a_steps, not b_steps]  # the waiting one, never the one that runs
    if a_steps and b_steps:
        assert refused == [b.me.before(a.me.started, a.me.ticket), a.me.before(b.me.started, b.me.ticket)]


def test_heartbeats_of_a_writer_that_is_no_world_node_neither_stop_nor_hold_back_a_world():
    me, forged = world(1000, 5), world(0, 0)  # ranks before every world, and steps
    me.heard(beat(forged, stepping=True))
    junk = [WORLD, ("_ros2cli_4711", "/", b"x")]
    assert me.refusal(False, junk) is None and me.refusal(True, junk) is None
    assert me.waits_for(junk) is None


def test_a_waiting_world_waits_to_learn_each_writers_node_and_to_hear_a_twin_in_the_graph():
    clock = Clock()
    me = world(1000, 5, clock)
    assert me.waits_for([WORLD]) is None and me.waits_for([]) is None
    assert "has not named it yet" in me.waits_for([WORLD, (UNKNOWN_NODE, "_NODE_NAMESPACE_UNKNOWN_", b"y")])
    assert "a heartbeat of the second /run7/world" in me.waits_for(BOTH)  # a twin, or a killed world's ghost
    later = world(1001, 1)
    me.heard(beat(later, stepping=False))
    assert me.waits_for(BOTH) is None and me.refusal(False, BOTH) is None  # heard, and it ranks after us
    clock.now += HEARD_FOR_BEATS * 1.0 + 0.1  # silent for three of its beats: it refused, or died
    assert me.waits_for(BOTH) is not None


def test_a_world_hears_its_own_heartbeats_as_nothing_and_keeps_few_twins():
    me = world(1000, 5)
    me.heard(beat(me, stepping=True))
    assert me.waits_for(BOTH) is not None  # its own heartbeat is no twin's
    for ticket in range(3 * KEPT):
        me.heard(Heartbeat(1, 0, 0, 1, 2000, ticket))
    assert len(me._heard) == KEPT
    assert me.refusal(False, BOTH)  # the newest are kept: they step


# -- on rclpy: two worlds in one namespace, at every timing -----------------------------------------------------
#
# Each world has a Context of its own (as a process of its own would), on the session's domain; waits are on
# events (a world's `done`, its episode), bounded.

CASE = (GRID[0], GRID[1], (*GRID[2], ("step_cap", 200)))


@contextlib.contextmanager
def worlds_in(domain_id: int, *identities: Identity, namespace: str, **params):
    """World nodes in `namespace`, each in a Context and on an executor of its own, waiting for agents that
    never come (startup_timeout beyond the test's waits); `spin()` turns every executor once."""
    contexts, nodes, executors = [], [], []
    try:
        for identity in identities:
            ctx = Context()
            rclpy.init(context=ctx, domain_id=domain_id)
            contexts.append(ctx)
            nodes.append(WorldNode(context=ctx, namespace=namespace, identity=identity,
                                   parameter_overrides=parameters(startup_timeout=120.0, **params)))
            executors.append(SingleThreadedExecutor(context=ctx))
            executors[-1].add_node(nodes[-1])

        def spin():
            for ex in executors:
                ex.spin_once(timeout_sec=0.01)
        yield nodes, spin
    finally:
        for ex in executors:
            ex.shutdown()
        for node in nodes:
            node.destroy_node()
        for ctx in contexts:
            rclpy.try_shutdown(context=ctx)


def _exactly_one_refuses(worlds, spin, refusing):
    wait_until(lambda: any(w.done.done() for w in worlds), 30.0, "a world's refusal", between=spin)
    # the other goes on hearing the refused one fall silent, for three of its heartbeats and more
    going_on = next(w for w in worlds if w is not refusing)
    wait_until(lambda: going_on.twins.waits_for([]) is None and not going_on.twins.fresh(), 30.0,
               "the refused world's silence", between=spin)
    assert refusing.done.result() == 2 and not going_on.done.done()


@pytest.mark.parametrize("order", ["first-ranks-before", "second-ranks-before"])
def test_of_two_worlds_waiting_for_their_agents_exactly_the_one_ranked_after_refuses(ros_domain_id, order):
    """Two worlds that both wait (no agents): decided by (started, ticket), not by which came first."""
    early, late = Identity(1_796_400_000, 9), Identity(1_796_400_000, 10)  # one second: the ticket decides
    identities = (early, late) if order == "first-ranks-before" else (late, early)
    with worlds_in(ros_domain_id, *identities, namespace=f"/{unique('twowait')}") as (worlds, spin):
        _exactly_one_refuses(worlds, spin, refusing=worlds[1] if order == "first-ranks-before" else worlds[0])


def test_a_second_world_started_inside_the_firsts_start_window_refuses_as_drawn(ros_domain_id):
    """Both worlds draw their identity as a launch's do, the second within a second of the first: the
    one ranked after refuses (the second, unless the two started in one second and the ticket says otherwise)."""
    first = Identity.draw()
    second = Identity.draw()
    with worlds_in(ros_domain_id, first, second, namespace=f"/{unique('window')}") as (worlds, spin):
        _exactly_one_refuses(worlds, spin, refusing=worlds[1] if first.before(second.started, second.ticket)
                             else worlds[0])


@pytest.mark.parametrize("when", ["as-it-begins", "long-after"])
def test_a_running_system_goes_on_beside_a_second_world_even_one_ranked_before_it(system_in, ros_domain_id,
                                                                                   spin_until, when):
    """A second world in the namespace of a system that steps (from its first step on, or after episodes of
    learning), given an identity ranked before every world: it finds the system's agents connected, refuses
    (exit 2) before its first step, so none of its messages reaches them; the system never refuses and its run
    is the engine's."""
    algo, episodes = "cq", 20
    system = system_in(algo, CASE[0], CASE[1], episodes, CASE[2], world_extra={"step_timeout": 10.0})
    began = 0 if when == "as-it-begins" else 3
    assert spin_until(system.executor, lambda: system.world.core.episode >= began, RUN_TIMEOUT_S)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=ros_domain_id)
    second = other = None
    try:
        second = WorldNode(context=ctx, identity=Identity(0, 0), parameter_overrides=parameters(
            map=CASE[0], episodes=episodes, seed=CASE[1], startup_timeout=RUN_TIMEOUT_S))
        other = SingleThreadedExecutor(context=ctx)
        other.add_node(second)
        wait_until(second.done.done, RUN_TIMEOUT_S, "the second world's exit",
                   between=lambda: (system.executor.spin_once(timeout_sec=0.01), other.spin_once(timeout_sec=0.01)))
        assert second.done.result() == 2
        assert second.core.episode == -1  # it never began: no message of it went out
    finally:
        if other is not None:
            other.shutdown()
        if second is not None:
            second.destroy_node()
        rclpy.try_shutdown(context=ctx)
    finish(system)  # every node exited 0: the running world never refused
    assert [(s.steps, s.collisions, s.truncated) for s in system.world_stats] == [
        (int(e["steps"]), int(e["collisions"]), bool(e["truncated"]))
        for e in offline_rows(algo, CASE[0], CASE[1], episodes, CASE[2])]


def test_a_heartbeat_squatter_before_a_keyed_start_neither_stops_nor_holds_back_the_run(system_in, ros_context,
                                                                                      spin_until, tmp_path):
    """Well-formed heartbeats of a world that steps and ranks before any, written from a node of another name
    from before the world starts (anyone who knows or guesses the namespace can): the keyed run starts, ends
    and is the engine's."""
    key = str(new_key_file(tmp_path))
    algo, episodes = "indep", 10
    # the world waits for a second world/stats subscriber, which comes once it has heard the squatter
    system = system_in(algo, CASE[0], CASE[1], episodes, CASE[2], common_extra={"key_file": key},
                       world_extra={"min_stats_subscribers": 2})
    squatter = system.add(rclpy.create_node("squatter", context=ros_context))
    pub = squatter.create_publisher(HEARTBEAT.msg_type, HEARTBEAT_TOPIC, profile(HEARTBEAT.qos))
    beats = iter(range(1, 10**9))
    squatter.create_timer(0.05, lambda: pub.publish(encode(Heartbeat(next(beats), 0, 0, 1, 0, 0))))
    assert spin_until(system.executor, lambda: bool(system.world.twins.fresh()), RUN_TIMEOUT_S)
    assert system.world.core.episode == -1  # heard while it waits
    squatter.create_subscription(WORLD_STATS.msg_type, WORLD_STATS_TOPIC, lambda _m: None, profile(WORLD_STATS.qos))
    finish(system)
    assert [(s.steps, s.collisions, s.truncated) for s in system.world_stats] == [
        (int(e["steps"]), int(e["collisions"]), bool(e["truncated"]))
        for e in offline_rows(algo, CASE[0], CASE[1], episodes, CASE[2])]
