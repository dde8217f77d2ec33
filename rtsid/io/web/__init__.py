"""The live web page of ``rtsid watch --web`` (server in :mod:`rtsid.io.web.server`; the page,
its script and the plotting library uPlot (MIT) in ``static/``)."""
