"""``sim2real adapt``: real -> sim -> real in one command (stages in ``pipeline``)."""
