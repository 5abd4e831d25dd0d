"""Races for classes and clubs: rules (ranking, windows, validation), storage, the track catalogue."""
