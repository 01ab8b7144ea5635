"""``python -m carlaocc.pipeline.cli``: the command line."""

from carlaocc.pipeline.cli import main

main()
