"""The chip layout of a plan (``vibroplan layout``): GDSII, geometry round trip, DRC."""
