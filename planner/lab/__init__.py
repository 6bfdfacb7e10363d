"""The lab's files: measured CSVs read, calibration fitted, drive waveforms exported."""
