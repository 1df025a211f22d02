"""The thin asyncio shell: rates, deadlines, task supervision, bounded peers and the record."""
