"""The kernel: the deterministic core runtime and the thin asyncio shell around it."""
