"""The figure renderers behind ``bench docs``: one module per benchmark, each rendering that benchmark's
figures (the blocks README.md and docs/*.md quote) from its files under docs/bench/."""

__all__: list[str] = []
