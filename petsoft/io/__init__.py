"""Files: recordings, XDMF output, summaries and importers of other tools' files."""
