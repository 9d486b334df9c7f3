"""The desktop application: PySide6 + pyvistaqt front end of the skelasm engine.

Nothing here is imported by ``engine/``. The window talks to the engine only through
:mod:`app.gui.session`, which wraps ``engine.runtime`` (commands in, immutable frames out) and
drains it on the GUI thread.
"""

#: Seconds after which ``skelasm gui --screenshot`` saves its picture and quits, when
#: ``--quit-after`` does not say.
SCREENSHOT_AFTER = 5.0
