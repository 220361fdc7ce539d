"""Files in and out: reading users' files safely (`files.py`), the sRGB transfer (`color.py`), and writing outputs
safely: the output-folder guard every writing command runs first (`guard.py`) and folders written whole or not at
all (`atomic.py`)."""
