"""``python -m sim2real`` is the ``sim2real`` console command."""

from sim2real.cli.main import console

console()
