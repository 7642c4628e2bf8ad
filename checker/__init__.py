"""checker package (see ../shared/DESIGN.md §1)."""
