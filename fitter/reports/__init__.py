"""reports"""


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend, imported when a figure is drawn: importing it with the
    package would cost every duhem command about 40 MB of memory and a second of start-up."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
