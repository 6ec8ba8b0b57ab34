"""The reports' pages: writing a page and its summary, the words reports speak, the front door
and the templates. Imports claims, grids and the store, never a figure."""
