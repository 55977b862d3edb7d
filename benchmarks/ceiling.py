#!/usr/bin/env python3
"""The messaging-only ceiling of a composed lockstep run: what the middleware allows, with our nodes taken out.

One world node and N agent nodes in one process, as `cq-ros launch --compose` runs them, on the same topics
(msgs_spec's names, types and QoS, the nodes' reader depth), publishing the serialized bytes of real keyed
payloads (msgs_spec.serialize, so every message has its run's size) straight to the publisher's handle and
reading them with raw subscriptions, on one EventsExecutor spun as node_runtime.run spins (one bounded call
until the step is done). A step: the world publishes the position of every AGV someone listens to, then every
feedback; an agent answers its feedback with an action once it also holds its peers' positions of the step
(`peers`: none, as independent learners, or every other agent's, as JS); the world steps again when every
action is in. Nothing is decoded, checked, learnt or counted but the arrivals: the gap between this rate and
a composed run's is our Python around each message. As the world node does, a position nobody listens to is
not sent (a writer with no reader still pays for its publish).

`--contract` puts back the wire contract alone: every message is built as its payload for the step (as the
nodes build theirs, each layout's `new`) and sealed with its node's key (msgs_spec.serialize), and every
arrival decoded with every check, the MAC included (bounds, agent, episode and step), as the nodes do; still
no driver, learner or world. The gap between the two rates is what the contract costs, the rest of a
composed run's gap is the nodes' own Python.

`--mac-only` makes and checks every message's MAC alone (the primed HMAC hashes copied, as msgs_spec.arrays does;
the bytes sent are the ceiling's, their MAC made anew): no payload, frame, seal, bounds or stamp check. No
contract sealed with this MAC can cost less in Python; the gap between it and `--contract` is the checks and
the payloads.

    python benchmarks/ceiling.py [--agents 16] [--steps 3000] [--peers none|all] [--contract | --mac-only]

Isolation: the environment's ROS_DOMAIN_ID, else a random one in 40..99, ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST,
its own rclpy Context; every wait is bounded (discovery, and each step).
"""

from __future__ import annotations

import argparse
import os
import secrets
import struct
import sys
import time
from functools import partial

from ros_tools.launch import BENCH_DOMAINS, run_domain

PEERS = ("none", "all")


def kind(contract: bool, mac_only: bool = False) -> str:
    """What a ceiling measures, as the benchmarks print it."""
    if mac_only:
        return "the messages and their MACs alone"
    return "the messages and the contract" if contract else "messaging-only ceiling"


def ceiling(agents: int, steps: int, peers: str = "none", warmup: int = 200, step_timeout_s: float = 5.0,
            discovery_timeout_s: float = 30.0, contract: bool = False, churn: float = 0.0,
            mac_only: bool = False) -> dict:
    """Steps per second of the emulated lockstep (`steps` timed after `warmup`), and the deliveries a step;
    with `contract`, every message encoded and decoded as the nodes do (the module's docstring)."""
    import rclpy
    from rclpy.task import Future

    from msgs_spec import (
        ACTION, ACTION_LAYOUT, FEEDBACK, FEEDBACK_LAYOUT, POSITION, POSITION_LAYOUT, Action, Bounds, Feedback,
        Position, action_topic, feedback_topic, position_topic, serialize,
    )
    from msgs_spec.auth import MAC_WORDS, WORLD, RunKey, new_run
    from node_runtime.qos import profile
    from node_runtime.rclpy_workarounds import raw_publisher, take_now
    from rclpy.event_handler import PublisherEventCallbacks

    from agent_node.node import UNANNOUNCED_CHECK_S
    from node_runtime.graph import Matched
    from node_runtime.run import FASTDDS_PROFILE, FASTDDS_PROFILE_ENV, make_executor
    from ros_tools.session import environment

    if peers not in PEERS:
        raise ValueError(f"peers {peers!r}: choose from {', '.join(PEERS)}")
    # Sealed messages, as a launch sends them (the seal's and the MAC's words make them longer): each node holds
    # the run's key as a RunKey of its own, bound to the run, as the nodes do (a bare key seals with run 0 and
    # checks the MAC alone, which no node does).
    secret, run = secrets.token_bytes(32), new_run()
    ids = range(1, agents + 1)
    keys = {k: RunKey(secret, run) for k in [WORLD, *ids]}  # the world's (WORLD) and each agent's
    position = {k: serialize(Position(k, 0, 1, 0, 0), key=keys[WORLD]) for k in ids}
    feedback = {k: serialize(Feedback(k, 0, 1, 0, 0, -1.0), key=keys[WORLD]) for k in ids}
    action = {k: serialize(Action(k, 0, 1, 0), key=keys[k]) for k in ids}
    bounds = Bounds(agents, 1, 1)
    clock = [0]  # the step, as the contract's payloads carry it
    if contract and mac_only:
        raise ValueError("contract or mac_only, not both")
    # What goes out: the same bytes every step (the ceiling); the payload of the step, sealed by its type's own
    # serializer as the nodes call it (contract); or the same bytes with their MAC made anew (mac_only).
    def make_position(k):
        return position[k]

    def make_feedback(k):
        return feedback[k]

    def make_action(k):
        return action[k]
    checked = contract or mac_only  # every arrival checked: decoded(layout, raw, sender, receiver)
    if contract:
        def decoded(layout, raw, k, receiver):  # what a node does with each arrival: decode with every check
            layout.decode(raw, bounds=bounds, agent=k, episode=0, step=clock[0], key=keys[receiver])

        def make_position(k):  # noqa: F811
            return POSITION_LAYOUT.serialize(POSITION_LAYOUT.new(k, 0, clock[0], 0, 0), keys[WORLD])

        def make_feedback(k):  # noqa: F811
            return FEEDBACK_LAYOUT.serialize(FEEDBACK_LAYOUT.new(k, 0, clock[0], 0, 0, -1.0, False, False, -1),
                                             keys[WORLD])

        def make_action(k):  # noqa: F811
            return ACTION_LAYOUT.serialize(ACTION_LAYOUT.new(k, 0, clock[0], 0), keys[k])
    if mac_only:
        # The floor of any contract sealed with this MAC in Python: per message sent, the HMAC of its values and
        # seal made from the primed hashes (as msgs_spec.arrays makes it) and the bytes joined; per arrival, its
        # HMAC made again and compared; no payload, frame, seal, bounds or stamp checked.
        def macked(layout):  # (where the values start, the MAC's Struct, the primed hashes)
            mac = struct.Struct(f"<{MAC_WORDS}{'I' if layout.code == 'i' else 'd'}")
            return layout.forms[1].start, mac, keys[WORLD].hashes(layout.label)
        forms = {lay: macked(lay) for lay in (FEEDBACK_LAYOUT, POSITION_LAYOUT, ACTION_LAYOUT)}
        words = struct.Struct(f">{MAC_WORDS}I")

        def mac_of(form, body):
            _, mac, (inner, outer) = form
            inner = inner.copy()
            inner.update(body)
            outer = outer.copy()
            outer.update(inner.digest())
            return mac.pack(*words.unpack_from(outer.digest()))

        def decoded(layout, raw, k, receiver):  # noqa: F811
            form = forms[layout]
            if not raw.endswith(mac_of(form, raw[form[0]:len(raw) - form[1].size])):
                raise RuntimeError("a MAC did not match")

        def remade(layout, sample):  # the message's bytes with its MAC made anew
            form = forms[layout]
            head, body = sample[:form[0]], sample[form[0]:len(sample) - form[1].size]
            return lambda k: head + body + mac_of(form, body)
        make_position = remade(POSITION_LAYOUT, position[1])  # noqa: F811
        make_feedback = remade(FEEDBACK_LAYOUT, feedback[1])  # noqa: F811
        make_action = remade(ACTION_LAYOUT, action[1])  # noqa: F811
    watched = {k: [j for j in ids if j != k] if peers == "all" else [] for k in ids}
    # churn: subscriptions made a step (at most 1), each to a peer's position topic for one decision step, as
    # CQ's agents make them; at the steps of a fixed schedule, the agents and their peers in turn.
    if not 0.0 <= churn <= 1.0 or (churn and peers != "none"):
        raise ValueError(f"churn {churn}: from 0 to 1 subscriptions a step, with peers none")
    schedule, owed = {}, 0.0
    for t in range(1, warmup + steps + 1):
        owed += churn
        if owed >= 1.0:
            owed -= 1.0
            k = len(schedule) % agents + 1
            schedule[t] = (k, k % agents + 1)
    created = [0]  # subscriptions made mid-run
    sends: dict = {}  # agent -> its arrival callback

    def position_at(k: int, t: int) -> bytes:
        return serialize(Position(k, 0, t, 0, 0), key=keys[WORLD])

    def on_match(k: int) -> None:
        if matched[k].count and k in held:
            send_position[k](position_at(k, held.pop(k)))
    domain = run_domain(None, BENCH_DOMAINS)
    namespace = f"/ceiling_{secrets.token_hex(4)}"
    env = {"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", FASTDDS_PROFILE_ENV: os.environ.get(
        FASTDDS_PROFILE_ENV, str(FASTDDS_PROFILE))}
    ctx = rclpy.Context()
    with environment(**env):
        rclpy.init(context=ctx, domain_id=domain)
    nodes, executor = [], None
    try:
        def node(name):
            made = rclpy.create_node(name, context=ctx, namespace=namespace, enable_rosout=False,
                                     start_parameter_services=False)
            nodes.append(made)
            return made

        world = node("world")
        # With churn, as the world node does: a position goes out while a reader is matched, the newest held
        # and sent on a match (a subscription made mid-run waits for it).
        matched = {k: Matched(then=partial(on_match, k)) for k in ids}
        held: dict[int, int] = {}  # agent -> the step of its newest position not sent
        pub_position = {k: world.create_publisher(POSITION.msg_type, position_topic(k), profile(POSITION.qos),
                                                  event_callbacks=PublisherEventCallbacks(matched=matched[k]))
                        for k in ids}
        pub_feedback = {k: world.create_publisher(FEEDBACK.msg_type, feedback_topic(k), profile(FEEDBACK.qos))
                        for k in ids}
        # Straight to the writer, as the nodes publish: what Publisher.publish(bytes) calls, without its checks
        send_position = {k: raw_publisher(pub) for k, pub in pub_position.items()}
        send_feedback = {k: raw_publisher(pub) for k, pub in pub_feedback.items()}
        listened = sorted({j for k in ids for j in watched[k]})
        actions_in = [0]
        stepped = [Future()]  # done once every action of the step is in
        subs = []
        for k in ids:
            def action_in(raw, k=k):
                if checked:
                    decoded(ACTION_LAYOUT, raw, k, WORLD)
                actions_in[0] += 1
                if actions_in[0] == agents:
                    stepped[0].set_result(True)

            subs.append(world.create_subscription(ACTION.msg_type, action_topic(k), action_in,
                                                  profile(ACTION.reader_qos), raw=True))
        need = {k: 1 + len(watched[k]) for k in ids}  # arrivals before agent k acts: its feedback and peers'
        got = dict.fromkeys(ids, 0)
        churning: dict[int, tuple] = {}  # agent -> (its subscription made at this step, the peer, the step)
        for k in ids:
            agent = node(f"agv{k}")
            pub = agent.create_publisher(ACTION.msg_type, action_topic(k), profile(ACTION.qos))

            def arrive(raw, k=k, send=raw_publisher(pub), sender=k, agent=agent):
                if checked:
                    decoded(FEEDBACK_LAYOUT if sender == k else POSITION_LAYOUT, raw, sender, k)
                if churn and sender == k:  # its feedback: the decision step of a subscription made mid-run
                    churn_step(agent, k)
                got[k] += 1
                if got[k] == need[k] + (k in churning):  # with churn, one more: the peer's position
                    got[k] = 0
                    send(make_action(k))
            sends[k] = arrive

            subs.append(agent.create_subscription(FEEDBACK.msg_type, feedback_topic(k), arrive,
                                                  profile(FEEDBACK.reader_qos), raw=True))
            for j in watched[k]:
                subs.append(agent.create_subscription(POSITION.msg_type, position_topic(j),
                                                      partial(arrive, sender=j), profile(POSITION.reader_qos),
                                                      raw=True))
        def churn_step(agent, k) -> None:
            """As a CQ agent at a conflict state: drop the subscription of its last decision, subscribe to the
            peer the schedule names for this one (each made inside the agent's callback, as the nodes do)."""
            if k in churning:
                agent.destroy_subscription(churning.pop(k)[0])
            j = schedule.get(clock[0])
            if j is not None and j[0] == k:
                peer = j[1]
                churning[k] = [agent.create_subscription(POSITION.msg_type, position_topic(peer),
                                                         partial(peer_in, k), profile(POSITION.reader_qos), raw=True),
                               peer, clock[0]]
                created[0] += 1

        def peer_in(k, raw) -> None:
            """A position of the subscription made at this step: counted once, when it is the one of this step
            (the writer's latched cache may hold an older one, and a later step's may come before it is dropped)."""
            held_by = churning.get(k)
            if held_by is not None and held_by[2] == clock[0] and raw == position_at(held_by[1], clock[0]):
                held_by[2] = None
                sends[k](raw, sender=held_by[1])

        executor = make_executor("events", ctx)
        for made in nodes:
            executor.add_node(made)
        deadline = time.monotonic() + discovery_timeout_s
        publishers = [*pub_position.values(), *pub_feedback.values()]
        while (any(p.get_subscription_count() < (1 if p in pub_feedback.values() else 0) for p in publishers)
               or any(s.get_publisher_count() < 1 for s in subs)):
            if time.monotonic() > deadline:
                raise RuntimeError(f"the ceiling's nodes did not discover each other within {discovery_timeout_s} s")
            executor.spin_once(timeout_sec=0.01)

        def step() -> None:
            actions_in[0] = 0
            clock[0] += 1
            if churn:
                for k in ids:
                    if matched[k].count:
                        send_position[k](position_at(k, clock[0]))
                    else:
                        held[k] = clock[0]
            for k in listened:
                send_position[k](make_position(k))
            for k in ids:
                send_feedback[k](make_feedback(k))
            # One call into the executor a step, until the last action is in, as node_runtime.run spins; with
            # churn, every UNANNOUNCED_CHECK_S a waited-for position the executor was never told of is taken
            # from its reader, as the agent node does (agent_node.peer_subscriptions).
            stop_at = time.monotonic() + step_timeout_s
            while True:
                executor.spin_until_future_complete(stepped[0], timeout_sec=UNANNOUNCED_CHECK_S if churn
                                                    else step_timeout_s)
                if stepped[0].done() or time.monotonic() > stop_at:
                    break
                for k, (sub, _, _) in list(churning.items()):
                    taken = take_now(sub)
                    if taken is not None:
                        peer_in(k, taken[0])
            if actions_in[0] < agents:
                raise RuntimeError(f"a ceiling step got {actions_in[0]} of {agents} actions in {step_timeout_s} s")
            stepped[0] = Future()

        for _ in range(warmup):
            step()
        started, cpu = time.perf_counter(), time.process_time()
        for _ in range(steps):
            step()
        seconds, cpu = time.perf_counter() - started, time.process_time() - cpu
    finally:
        if executor is not None:
            executor.shutdown()
        for made in nodes:
            made.destroy_node()
        rclpy.try_shutdown(context=ctx)
    return {"agents": agents, "peers": peers, "contract": contract, "mac_only": mac_only, "steps": steps,
            "seconds": seconds,
            "steps_per_s": steps / seconds,
            "cpu_ms_per_step": cpu / steps * 1e3,
            "subscriptions_made_per_step": created[0] / (warmup + steps),
            "messages_per_step": 2 * agents + len(listened),
            "deliveries_per_step": 2 * agents + sum(map(len, watched.values()))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--agents", type=int, default=16)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--peers", choices=PEERS, default="none")
    ap.add_argument("--contract", action="store_true", help="encode and decode every message as the nodes do")
    ap.add_argument("--mac-only", action="store_true",
                    help="only make and check every message's MAC: the floor of any contract with it")
    ap.add_argument("--churn", type=float, default=0.0,
                    help="peer subscriptions made a step (0-1, peers none), each for one decision step, as CQ's")
    args = ap.parse_args(argv)
    if args.agents < 1 or args.steps < 1:
        print("ceiling.py: --agents and --steps must be at least 1", file=sys.stderr)
        return 2
    r = ceiling(args.agents, args.steps, args.peers, contract=args.contract, churn=args.churn,
                mac_only=args.mac_only)
    print(f"{kind(r['contract'], r['mac_only'])}, {r['agents']} agents, peers {r['peers']}: "
          f"{r['steps_per_s']:,.0f} steps/s "
          f"({r['steps']} steps in {r['seconds']:.2f} s, {r['cpu_ms_per_step']:.3f} ms of CPU a step; "
          f"{r['deliveries_per_step']} deliveries and {r['subscriptions_made_per_step']:.2f} subscriptions made a "
          "step); "
          f"load average {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
