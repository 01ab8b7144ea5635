"""``python -m carlaocc``: the command line (same as the ``carlaocc`` script)."""

from carlaocc.pipeline.cli import main

if __name__ == "__main__":
    main()
