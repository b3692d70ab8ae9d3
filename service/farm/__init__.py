"""The farm management system's view: orchards, rows, trees, measurements and CSV export."""
