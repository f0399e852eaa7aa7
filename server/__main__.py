"""``m3p2i-server`` and ``python -m server``: the world process's entry point."""

import gc


def main() -> None:
    """Run the world CLI, its imports and its world built with the garbage collector off (the
    CLI turns it back on: :func:`shared.cli_common.collector_back`)."""
    gc.disable()
    from server.cli import app

    app(prog_name="m3p2i-server")


if __name__ == "__main__":
    main()
