"""The run store: the run directory, its journal's records and the file formats it writes."""
