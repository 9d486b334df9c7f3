"""skelasm's application: the `skelasm` command line and the PySide6 + PyVista GUI.

Only the GUI modules import Qt; the command line's headless commands do not.
"""
