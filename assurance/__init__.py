"""Runtime assurance: the pure decision core of warden.

Nothing in this package imports asyncio, sockets, threads or a vendor SDK. Every function takes
time as an argument (integer nanoseconds on the client's monotonic clock) and returns values.
"""
