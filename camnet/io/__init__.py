"""Codecs: observation and calibration JSON, rig files, session files, exports, the report, atomic writes."""
