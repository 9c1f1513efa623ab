"""The live 3D view (viser): the view itself, its pure geometry, and how it follows the server."""
