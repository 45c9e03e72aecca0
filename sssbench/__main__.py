"""``python -m sssbench``: the same Hydra app as the ``sssbench`` console script."""

from sssbench.app import main

if __name__ == "__main__":
    main()
