"""The kernel's pure core: events in, decisions and decision-log lines out.

No asyncio, sockets, threads, wall clock or vendor SDK: time arrives as an argument, so the same
code decides a live run and its replay, bit for bit.
"""
