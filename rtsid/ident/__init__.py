"""Pure numerics of rtsid: arrays in, numbers out. No threads, files or sockets.

Imports nothing of rtsid but :mod:`rtsid.errors`.
"""
