"""What a flight leaves behind: the MCAP run log and the camera renders that go into it."""
