"""Camera models shared by every stage."""
