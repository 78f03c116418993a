"""What the commands do, without the command line: learn, info, merge, demo."""
