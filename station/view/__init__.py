"""What people look at: the Rerun live view and the PNG plots."""
