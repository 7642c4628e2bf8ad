"""experiments package (see ../shared/DESIGN.md §1)."""
