"""A client for labs: talk to a running ``legws daemon`` from your own Python.

::

    from legws_daemon.client import Client

    with Client.from_profile("sim") as daemon:        # or Client.from_config("lab.json5")
        status = daemon.status()                       # the newest status (waits for one)
        print(status.mode, status.targets, status.started)
        reply = daemon.command("load_taskgraph", "tea")
        with daemon.joystick("my-client") as stick:    # the operator's stick
            stick.publish((0.0, 0.5, 0.0), Buttons(enable=True))
        for event in daemon.events(timeout=30):        # commit, stage_done, warning ...
            print(event.kind, event.detail)

Everything it receives is validated (:mod:`legws_daemon.formats.messages`); the wire format
is docs/messages.md. The session is opened by ``with`` and always closed.
"""

from legws_daemon.client.client import Client, CommandRefusedError, Reply

__all__ = ["Client", "CommandRefusedError", "Reply"]
