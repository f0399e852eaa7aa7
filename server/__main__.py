from server.cli import app

app(prog_name="m3p2i-server")
