"""Subcommands of `skelasm`: one module each, with ``add_parser(subparsers)`` and ``run(args)``.

Command modules import heavy packages inside ``run`` so that ``skelasm --help`` stays fast
and headless commands never load Qt.
"""
