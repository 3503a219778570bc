"""Output helpers the benchmark scripts share: a printed and written table, and pyplot when installed."""

from pathlib import Path


def publish(path: Path, text: str) -> None:
    """Write `text` (a markdown table) to `path` and print it."""
    Path(path).write_text(text)
    print(text)


def pyplot():
    """`matplotlib.pyplot` on the non-interactive Agg backend, or None when matplotlib is not installed."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return None
    return plt
