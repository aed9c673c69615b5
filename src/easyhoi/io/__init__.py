"""Reading and writing files: photos and masks (``image``), results and exports."""
