"""One package per stage, named as in configurations: ``stage.py`` is the driver."""
