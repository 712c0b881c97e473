"""``python -m tofmetry.cli``: the ``tofmetry`` command."""

from tofmetry.cli import main

if __name__ == "__main__":
    main()
