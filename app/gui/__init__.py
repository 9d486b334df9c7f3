"""The desktop application: PySide6 + pyvistaqt front end of the skelasm engine.

Nothing here is imported by ``engine/``. The window talks to the engine only through
:mod:`app.gui.session`, which wraps ``engine.runtime`` (commands in, immutable frames out) and
drains it on the GUI thread.
"""
