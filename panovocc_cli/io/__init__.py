"""One module per on-disk format, each a ``read_*`` / ``write_*`` pair; all writes are atomic."""
