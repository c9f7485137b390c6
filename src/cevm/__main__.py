"""``python -m cevm``: the command line (:func:`cevm.cli.main`)."""

from cevm.cli import main

if __name__ == "__main__":  # importing this module (pkgutil, the API reference's autosummary) runs nothing
    main()
