"""The write policy and the files it writes: atomic writes (io), digests (integrity), owner
records (ownership), run locks (locks), Parquet and table files (parquet, tables)."""
