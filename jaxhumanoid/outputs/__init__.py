"""What people look at: solutions on disk, reports, figures, animations, the command line."""
