"""The command line's entry point: ``cevm`` (the console script) and ``python -m cevm``.

The stop signals' handlers come first, before the command line's modules are imported
(:mod:`cevm.stops`): a SIGTERM or SIGINT in a command's first instant is one line and
exit 143 or 130, as it is later."""

from cevm import stops


def main() -> None:
    """Run the command of ``sys.argv`` (:func:`cevm.cli.main`), the handlers installed."""
    stops.install()
    from cevm.cli import main as cli_main

    cli_main()


if __name__ == "__main__":
    main()
