"""estimation: least squares, identification, uncertainty, design of experiments"""
