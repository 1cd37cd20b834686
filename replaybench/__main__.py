"""``python -m replaybench``."""

from replaybench.cli import main

main()
