"""The mission file: its models, its loader with located errors, and what ``zab check`` says."""
