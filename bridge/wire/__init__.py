"""What travels on the water, pure: channel tables, the frame, authentication, payloads."""
