"""``python -m legws_daemon`` is ``legws``."""

from legws_daemon.cli.main import main

main()
