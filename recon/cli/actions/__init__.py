"""What each command does: imported by ``recon.cli.parsing.run_by`` when the command runs."""
