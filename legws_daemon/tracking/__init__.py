"""Where the objects really stand: fiducial markers seen by a camera (``legws track``)."""
