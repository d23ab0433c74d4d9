"""edge-ips: optical indoor positioning for small robot fleets."""

import os as _os

# OpenCV and FFmpeg write their own warnings to stderr ("[ WARN:0@0.07] global cap.cpp ...", "moov atom not
# found"); edge-ips says what failed in one line of its own. Set before any module imports cv2.
_os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")
_os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
