"""``python -m protorch experiment=<name> [key=value ...]``: the Hydra app
(:mod:`protorch.app.main`)."""

from protorch.app.main import main

if __name__ == "__main__":
    main()
