"""The parsers of `cq-ros`'s ROS commands (their bodies: ros.py): launch, collect, view, checkpoint, key,
hosts, echo, topics, nodes and record.
"""

from __future__ import annotations

from ..learners import LEARNERS
from .arguments import (Parser, add_domain_option, add_settings_options, algo_name, domain_id, episode_count,
                        nonempty_path, number, positive_int, seconds, seed_int)


def add_ros_parsers(sub) -> None:
    p = sub.add_parser("launch", help="run one algorithm on one map as ROS 2 nodes (a world process and one "
                                      "process per AGV) and write results and figures",
                       epilog="exit status: 0 every episode played as the offline engine plays it; 3 every episode "
                              "played, but some step was not (a missed or unapplied action, a feedback never "
                              "heard: the last line says how many episodes); 1 the launch failed or ended early; "
                              "2 bad arguments; 130 interrupted. manifest.json says how every launch ended "
                              "(`ended`).")
    p.add_argument("--map", default=None, help="a shipped map name or a path to a map file (required unless "
                                                "--params-file)")
    p.add_argument("--algo", type=algo_name, default=None, help=f"one of {','.join(LEARNERS)} (required unless "
                                                             "--params-file)")
    p.add_argument("--out", type=nonempty_path, required=True, help="result directory (node logs in its logs/; the "
                                                           "system it ran in its params.yaml)")
    p.add_argument("--params-file", type=nonempty_path, default=None, metavar="FILE",
                   help="start the system a params.yaml describes (as every launch writes it: map, algorithm, "
                        "episodes, seed, settings and node parameters, under any namespace) instead of --map, "
                        "--algo, --episodes, --seed, --set")
    p.add_argument("--key", type=nonempty_path, default=None, metavar="FILE",
                   help="key the run with this key file (made by `cq-ros key`), named in params.yaml and kept "
                        "(default: a key of the launch's own, in a file without a name)")
    p.add_argument("--restart-agents", type=number(0, 1000, kind=int), default=0, metavar="N",
                   help="start an agent node that dies again, from its checkpoint, up to N times in all (default 0: "
                        "a node that dies ends the launch); its checkpoint is saved every --set checkpoint_every=E "
                        "learning episodes (default 50), and the episodes it learnt past it are lost: counted per "
                        "restart on stderr and in the manifest (`restarts.learning_lost`)")
    p.add_argument("--view", type=number(0, 65535, kind=int), default=None, metavar="PORT",
                   help="serve the run live to Foxglove on ws://127.0.0.1:PORT, as cq-ros view (the extra `view`; "
                        "0: any free port, printed at start)")
    p.add_argument("--episodes", type=episode_count, default=None, help="episodes (default 500)")
    p.add_argument("--seed", type=seed_int, default=None, help="master seed (default 0)")
    p.add_argument("--domain-id", type=domain_id, default=None, metavar="N",
                   help="ROS_DOMAIN_ID of the run (default: the environment's ROS_DOMAIN_ID, else random in 100..200)")
    p.add_argument("--namespace", default=None,
                   help="ROS namespace of the run, e.g. /demo or demo (default: random cq_<hex>)")
    p.add_argument("--step-timeout", type=seconds, default=2.0, metavar="S",
                   help="seconds the world waits for an action before the agent stays (default 2)")
    p.add_argument("--peer-linger-steps", type=number(0, kind=int), default=None, metavar="N",
                   help="decision steps an agent keeps a peer subscription it no longer needs (default: the "
                        "agent node's, 0)")
    p.add_argument("--compose", action="store_true",
                   help="run every node in one process on one executor (a component container) instead of a "
                        "process per node")
    p.add_argument("--executor", choices=("events", "single"), default=None,
                   help="the nodes' executor: rclpy's EventsExecutor (default) or the SingleThreadedExecutor")
    p.add_argument("--hosts", default=None, metavar="PREFIX",
                   help="run each node on its own host made by `cq-ros hosts up` (root; re-runs itself on the "
                        "world's host)")
    p.add_argument("--discovery", choices=("subnet", "static"), default=None,
                   help="with --hosts: multicast discovery on the subnet (default), or unicast to ROS_STATIC_PEERS "
                        "only")
    p.add_argument("--no-figures", dest="figures", action="store_false", help="write the tables only")
    add_settings_options(p, nodes=True)

    p = sub.add_parser("collect", help="listen to a system started by hand (its statistics) and write what a "
                                       "launch writes: episodes.csv, greedy.csv, observe.csv, manifest.json")
    p.add_argument("--out", type=nonempty_path, required=True, help="result directory")
    p.add_argument("--namespace", default=None, help="the system's namespace (default: the one system on the domain)")
    p.add_argument("--wait", type=seconds, default=60.0, metavar="S",
                   help="seconds to look for the system before giving up (default 60)")
    p.add_argument("--force", action="store_true", help="overwrite an existing result directory")
    add_domain_option(p)

    p = sub.add_parser("view", help="a live view in Foxglove: a Foxglove WebSocket server relaying a running "
                                    "system's topics with their ROS 2 schemas, until Ctrl-C (extra `view`)")
    p.add_argument("--namespace", default=None, help="the system's namespace (default: the one system on the domain)")
    p.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1)")
    p.add_argument("--port", type=number(0, 65535, kind=int), default=8765, help="port (default 8765; 0: any free)")
    p.add_argument("--wait", type=seconds, default=60.0, metavar="S",
                   help="seconds to look for the system before giving up (default 60)")
    add_domain_option(p)

    p = sub.add_parser("checkpoint", help="agent checkpoints: convert one of the old pickled format (3) into the "
                                          "current one (.npz, which loads without running code)")
    actions = p.add_subparsers(dest="action", required=True, parser_class=Parser)
    p = actions.add_parser("convert", help="write a pickled checkpoint (format 3) as an .npz checkpoint",
                           description="Unpickle OLD and write it as the .npz checkpoint NEW. Unpickling runs "
                                       "whatever code the file holds: run it only on a checkpoint you trust (one your "
                                       "own cq-ros wrote).")
    p.add_argument("old", type=nonempty_path, metavar="OLD", help="a pickled checkpoint (.pkl) you trust")
    p.add_argument("new", type=nonempty_path, metavar="NEW", help="the .npz checkpoint to write (never overwritten)")

    p = sub.add_parser("key", help="make a key file for a system kept in a parameters file (its key_file; "
                                   "cq-ros launch --key FILE)")
    p.add_argument("--out", type=nonempty_path, required=True, metavar="FILE", help="the key file to make (mode 0600; "
                                                                            "never overwritten)")

    p = sub.add_parser("hosts", help="make or remove hosts for --hosts: network namespaces joined by a bridge, "
                                     "addresses from 198.18.0.0/15 (root)")
    p.add_argument("action", choices=("up", "down", "list"),
                   help="up: make a world host and one per AGV; down: remove them; list: the sets there are")
    p.add_argument("--agents", type=positive_int, default=2, help="up: AGV hosts (default 2)")
    p.add_argument("--prefix", default=None,
                   help="the set's name: cqr and up to 8 letters or digits (up: default random; down: required)")

    p = sub.add_parser("echo", help="print the messages of a topic as YAML, like `ros2 topic echo`")
    p.add_argument("topic", help="topic name, e.g. /cq_1a2b3c4d/agv1/position")
    p.add_argument("--count", type=positive_int, default=None, metavar="N", help="exit after N messages")
    p.add_argument("--timeout", type=seconds, default=None, metavar="S",
                   help="exit after S seconds (code 1 if no message came)")
    add_domain_option(p)

    for name, what in (("topics", "the live topics, like `ros2 topic list`"),
                       ("nodes", "the live nodes with their namespaces, like `ros2 node list`")):
        p = sub.add_parser(name, help=f"list {what}")
        if name == "topics":
            p.add_argument("-t", "--show-types", dest="show_types", action="store_true", help="show each topic's type")
        else:
            p.add_argument("-a", "--all", dest="all_nodes", action="store_true", help="show hidden nodes too")
        p.add_argument("--wait", type=seconds, default=None, metavar="S",
                       help="list once the graph has not changed for 3.5 s, waiting S seconds at most (default 15)")
        add_domain_option(p)

    p = sub.add_parser("record", help="record topics to a rosbag2 file (default: every cq_ros topic)")
    p.add_argument("--out", type=nonempty_path, required=True, help="bag directory to create")
    p.add_argument("--topics", nargs="+", default=None, metavar="TOPIC", help="record these topics only")
    p.add_argument("--duration", type=seconds, default=None, metavar="S", help="stop after S seconds")
    p.add_argument("--count", type=positive_int, default=None, metavar="N", help="stop after N messages")
    p.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap", help="storage plugin (default mcap)")
    p.add_argument("--namespace", default=None,
                   help="record one system's topics: those under this namespace, against which relative --topics "
                        "resolve (default: every cq_ros topic, under any namespace)")
    add_domain_option(p)
