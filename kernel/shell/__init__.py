"""The thin asyncio shell: rates, deadlines, task supervision and bounded channels."""
