"""How a node process's run loop (node_runtime.run.run_node) ends: with its exit code and no traceback, wherever
Ctrl-C lands."""

import sys

import pytest
import rclpy

from node_runtime import run


@pytest.mark.ros
def test_ctrl_c_landing_while_the_loop_handles_the_shut_down_contexts_error_is_exit_130(monkeypatch, ros_domain_id):
    """Ctrl-C is two events: rclpy's handler shuts the context down, so the spin raises RCLError; Python's
    KeyboardInterrupt then lands at the next bytecode, here inside the handler of that error (rclpy.ok()). A
    launcher's SIGINT to a busy agent did so once in a suite run beside two busy loops (a traceback in agv1.log)."""
    def shut_down_context():
        raise RuntimeError("failed to initialize wait set: the given context is not valid")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(sys, "argv", ["agent_node"])
    monkeypatch.setattr(run.rclpy, "ok", interrupted)
    assert run.run_node(shut_down_context, "agent_node", ()) == 130
    assert not rclpy.utilities.get_default_context().ok()  # the context it made is shut down
