"""``python -m railstop.cli``: the ``railstop`` command (the live runner starts its processes so)."""

from railstop.cli import main

if __name__ == "__main__":
    main()
